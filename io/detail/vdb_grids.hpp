// The OpenVDB grids behind io::SparseGrid, for .cpp files of io and later layers
// that iterate them (e.g. GMF sampling). Heavy include: never from a public header.
#pragma once

#include <openvdb/openvdb.h>

#include "io/sparse_grid.hpp"

namespace hisnegs::io {

struct SparseGrid::Impl {
  openvdb::FloatGrid::Ptr volume;      // foreground + band, values = normalized intensities
  openvdb::FloatGrid::Ptr background;  // random subsample of the rest (may be empty, never null)
  SparseGridMeta meta;
};

namespace detail {
// openvdb::initialize() exactly once per process (thread-safe).
void ensure_openvdb_initialized();
// The CONVENTIONS index->world map as an OpenVDB linear transform.
openvdb::math::Transform::Ptr make_vdb_transform(const WorldFrame& frame);
}  // namespace detail

}  // namespace hisnegs::io
