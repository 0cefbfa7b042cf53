// SPDX-License-Identifier: Apache-2.0
// Sparse OpenVDB form of a normalized volume: a `volume` FloatGrid holding the
// foreground (voxels above a threshold) dilated by a band, an optional
// `background` grid with a random subsample of the rest, the CONVENTIONS
// index->world transform, and .vdb read/write with metadata. OpenVDB itself is
// hidden here: later layers visit the active voxels (visit_active_leaves).
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "io/volume.hpp"

namespace hisnegs::io {

// How a volume becomes sparse (config section `sparse_grid`).
struct SparseGridOptions {
  double threshold = 0.05;  // normalized value above which a voxel is foreground, [0, 1)
  int band_voxels = 2;      // dilation of the foreground, steps of the 26-neighbourhood, [0, 32]
  // Share of the remaining voxels sampled into `background`, [0, 1]. 0 keeps the
  // .vdb compact (scattered samples cost an 8^3 leaf each); the GMF fit sets its
  // own (gmf.background_fraction).
  double background_fraction = 0.0;
  std::uint64_t seed = 0;  // seed of the background subsample

  void validate() const;  // throws InputError("sparse_grid.FIELD = VALUE: rule")
  template <class V>
  void visit(V&& v) {
    v("threshold", threshold);
    v("band_voxels", band_voxels);
    v("background_fraction", background_fraction);
    v("seed", seed);
  }
};

// One active voxel of a SparseGrid: its integer index (x, y, z) and value.
struct ActiveVoxel {
  std::array<int, 3> index;
  float value;
};

// The two grids of a SparseGrid.
enum class SparseGridPart { kForeground, kBackground };

// What a .vdb written by hisnegs records about its source volume.
struct SparseGridMeta {
  std::array<int, 3> shape_xyz{0, 0, 0};  // X, Y, Z of the source stack
  std::array<double, 3> spacing_um{1.0, 1.0, 1.0};
  Eigen::Vector3d aspect{1, 1, 1};  // world half-extents
  Normalization normalization;
  std::string source;
  SparseGridOptions options;  // how it was built
};

class SparseGrid {
 public:
  struct Impl;  // defined in io/detail/vdb_grids.hpp
  SparseGrid();
  explicit SparseGrid(std::shared_ptr<Impl> impl);

  [[nodiscard]] std::int64_t active_voxels() const;      // in `volume` (foreground + band)
  [[nodiscard]] std::int64_t background_voxels() const;  // in `background` (0 when not sampled)
  [[nodiscard]] std::int64_t leaf_count() const;         // 8^3 leaves of `volume`
  [[nodiscard]] std::size_t memory_bytes() const;        // both grids, as OpenVDB counts it
  [[nodiscard]] const SparseGridMeta& meta() const;
  [[nodiscard]] WorldFrame frame() const;  // the CONVENTIONS frame of the source stack
  // Value stored at integer voxel (x, y, z) of `volume` and whether it is active.
  [[nodiscard]] float value(int x, int y, int z, bool* active = nullptr) const;

  // Calls visit(leaf_origin, voxels) for every 8³ leaf of `part` holding active
  // voxels: the leaf's first voxel index (multiples of 8) and its active voxels, both
  // in OpenVDB's order (deterministic for a given grid).
  using LeafVisitor = std::function<void(const std::array<int, 3>& leaf_origin, std::span<const ActiveVoxel> voxels)>;
  void visit_active_leaves(SparseGridPart part, const LeafVisitor& visit) const;

  // Where the 8³ leaf at `leaf_origin` comes in visit_active_leaves' order (the
  // tree's: root tiles, then each internal level's children): leaves sorted by
  // this key are in the order the grid visits them.
  [[nodiscard]] static std::array<int, 9> leaf_order_key(const std::array<int, 3>& leaf_origin);

  // io's own code and tests only (io/detail/vdb_grids.hpp).
  [[nodiscard]] const Impl& impl() const { return *impl_; }

 private:
  std::shared_ptr<Impl> impl_;
};

// Builds the sparse grids from a (normalized) volume. TBB-parallel over 8^3 bricks.
// Throws InputError if options are invalid.
SparseGrid build_sparse_grid(const Volume& volume, const Eigen::Vector3d& aspect, const SparseGridOptions& options);

class VolumeSource;  // io/volume_source.hpp
// The same grids (voxel for voxel, background samples included) from a stack read by
// regions: tiles of tile_voxels (a positive multiple of 8) on each axis, each read with
// band_voxels around it and normalized by `normalization`, so memory holds one tile
// and its band as float32 (plus the grids: foreground, band and samples). Calls
// on_tile(done, total) after each tile. With `take_background`, each tile's
// background leaves are handed to it (leaf origin and active voxels, tile by tile)
// instead of kept in the grid: scattered samples cost an 8³ leaf each, as much as
// the stack itself on a large one. Throws what the source's read throws, and
// std::invalid_argument for a tile_voxels that is not a multiple of 8.
SparseGrid build_sparse_grid(const VolumeSource& source, const Normalization& normalization,
                             const Eigen::Vector3d& aspect, const SparseGridOptions& options, int tile_voxels,
                             const std::function<void(int done, int total)>& on_tile = {},
                             const SparseGrid::LeafVisitor& take_background = {});

// Writes `volume` (+ `background`) grids with metadata, atomically.
void write_vdb(const std::filesystem::path& path, const SparseGrid& grid);
// Reads a .vdb written by write_vdb. Throws InputError naming the file if it is not
// a VDB, lacks a float grid named `volume`, or its metadata are missing/invalid.
SparseGrid read_vdb(const std::filesystem::path& path);

// A look at any .vdb (not only hisnegs'): one entry per grid.
// Grids whose leaf values the structural walk cannot check (point data: OpenVDB's
// attribute arrays state their own sizes) are not loaded: their counts, memory
// and box come from the statistics the writer stored (-1 where it stored none).
struct VdbGridSummary {
  std::string name;
  std::string value_type;
  std::string grid_class;
  bool values_read = false;  // loaded by OpenVDB (else metadata and transform only)
  std::int64_t active_voxels = -1;
  std::int64_t leaf_count = -1;
  std::int64_t memory_bytes = -1;
  std::array<int, 3> bbox_min{0, 0, 0}, bbox_max{0, 0, 0};  // active index bounding box
  std::array<double, 3> voxel_size{1, 1, 1};                // world units
  std::map<std::string, std::string> metadata;
};
std::vector<VdbGridSummary> inspect_vdb(const std::filesystem::path& path);

}  // namespace hisnegs::io
