// SPDX-License-Identifier: Apache-2.0
// How a stage that reads the stack holds it: whole when it fits in the memory the
// user allows, else brick by brick (the ground truth's march, the sparse grid of the
// volume stage and of training's 3D term). The bricked results equal the whole
// stack's, so the choice is not part of a stage's fingerprint, with one exception:
// a float32 stack with percentile normalization, whose streamed percentiles come
// from a binned histogram (within one bin width of the exact ones, io::
// scan_statistics), so its normalization, and all that follows, may differ slightly. The statistics of a
// stack read by bricks (one streaming pass) can be cached in a run folder, so the
// stages of one run do not repeat the pass.
#pragma once

#include <array>
#include <filesystem>
#include <string>

#include "apps/pipeline/progress.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"
#include "io/volume_source.hpp"

namespace hisnegs::apps {

struct StackReading {
  std::string max_memory = "auto";  // "auto" (half the RAM), or a size: 1GiB, 512MiB
  int brick_voxels = 0;             // > 0: bricks of this core edge even when the stack fits
  std::filesystem::path statistics_cache;  // a JSON file for the streaming pass' result; empty: none
};

// What one stage needs to hold a brick: a fixed part and bytes per voxel of the brick's
// core with `halo` voxels around it on each side.
struct BrickNeed {
  double base_bytes = 112.0 * 1048576.0;
  double bytes_per_voxel = 8.0;
  int halo = 1;
  int smallest = 16;  // the smallest core edge worth planning
};

// What the sparse grid of a stack of `stack_voxels` needs by tiles: each tile's
// voxels and the band around them as float32, as much again for a tile's scattered
// background leaves when background_fraction > 0, and the background samples of
// the whole stack: handed over as float samples (20 bytes each, twice for growth)
// when `background_taken` (training's 3D term), else kept in the grid, where each
// scattered sample costs an 8³ leaf of its own (at most one per leaf of the stack).
// The foreground grid itself is not counted: it is what the stage makes, in
// proportion to the foreground, which is not known before the pass.
[[nodiscard]] BrickNeed sparse_grid_need(const io::SparseGridOptions& sparse, double stack_voxels,
                                         bool background_taken);

// The core edge in voxels of the bricks `what` reads a stack of `shape` (x, y, z) in:
// 0 when the whole stack fits under reading.max_memory, reading.brick_voxels when it
// is set, else the largest multiple of 16 whose brick fits (one line saying so).
// Throws io::InputError when not even the smallest brick fits or the size does not parse.
[[nodiscard]] int reading_core(const std::array<int, 3>& shape, const StackReading& reading, const BrickNeed& need,
                               const std::string& what, const Progress& progress);

// The normalization load_volume would give `source` (the file `volume`, read with
// `options`): from reading.statistics_cache when it holds the pass of this very file
// (size, time, inode) and these options, else one streaming pass, then cached there.
// A cache that cannot be written is said through `progress`, not thrown. Shared
// (the ranks of a job, all calling it): each reads the cache (the same file, so the
// same answer) or its share of the pages; part 0 writes the cache.
[[nodiscard]] io::Normalization source_normalization(const io::VolumeSource& source, const io::VolumeOptions& options,
                                                     const std::filesystem::path& volume, const StackReading& reading,
                                                     const Progress& progress = Progress{},
                                                     const io::ScanShare& share = {});

// The sparse grid of `volume` (volume options, sparse options): from the loaded stack
// when it fits, else built tile by tile from its source (io::build_sparse_grid), the
// same grid. One line "WHAT: ..." when it reads by tiles. When it reads by tiles
// and `take_background` is set, the background samples go to it tile by tile instead
// of into the grid (io::build_sparse_grid); a stack loaded whole keeps them in the grid.
[[nodiscard]] io::SparseGrid read_sparse_grid(const std::filesystem::path& volume, const io::VolumeOptions& options,
                                              const io::SparseGridOptions& sparse, const StackReading& reading,
                                              const std::string& what, const Progress& progress,
                                              const io::SparseGrid::LeafVisitor& take_background = {});

}  // namespace hisnegs::apps
