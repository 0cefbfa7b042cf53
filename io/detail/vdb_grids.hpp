// SPDX-License-Identifier: Apache-2.0
// The OpenVDB grids behind io::SparseGrid (its pimpl), for io's own .cpp files and
// tests. Other layers use SparseGrid::visit_active_leaves and io/vdb_file.hpp.
#pragma once

#include <openvdb/openvdb.h>

#include "io/sparse_grid.hpp"

namespace hisnegs::io {

struct SparseGrid::Impl {
  openvdb::FloatGrid::Ptr volume;      // foreground + band, values = normalized intensities
  openvdb::FloatGrid::Ptr background;  // random subsample of the rest (may be empty, never null)
  SparseGridMeta meta;
};

}  // namespace hisnegs::io
