// The OpenVDB grids behind io::SparseGrid, for .cpp files of io and later layers
// that iterate them (e.g. GMF sampling). Heavy include: never from a public header.
#pragma once

#include <openvdb/openvdb.h>

#include <filesystem>

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
// Writes `grids` to a .vdb file (Blosc) atomically; an OpenVDB failure becomes a
// std::runtime_error naming `path`, and leaves no file.
void write_vdb_file(const std::filesystem::path& path, const openvdb::GridPtrVec& grids);
}  // namespace detail

}  // namespace hisnegs::io
