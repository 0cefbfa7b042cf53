// SPDX-License-Identifier: Apache-2.0
// How a fit is planned under a memory limit: the in-memory fit when the stack fits,
// else bricks (gmf/bricked/brick_plan.hpp) as large as the limit allows, or two or more per
// MPI rank. The memory model is measured (docs/benchmarks.md "Stacks larger than
// memory"); the planner refuses a limit that not even the smallest brick fits.
#pragma once

#include <array>
#include <cstddef>
#include <functional>
#include <string>

#include "gmf/bricked/brick_plan.hpp"
#include "gmf/gmf_options.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

// The largest scale of a bricked fit, world units (gmf.stream_scale_voxels of the
// smallest voxel side): what bounds the halo.
[[nodiscard]] double brick_max_scale(const io::WorldFrame& frame, const GmfOptions& gmf);

// The fit's peak memory as a function of what it holds at once: a base (the
// program, its libraries and thread pools), bytes per voxel of the volume or brick
// region in memory (float32 voxels, the foreground mask, the sparse grid, the samples,
// the block index) and bytes per Gaussian of the whole model. Measured with
// /usr/bin/time -v on this repository's stacks (docs/benchmarks.md "Stacks larger
// than memory"); a model, not a promise: the limit is planned with it.
struct FitMemoryModel {
  double base_bytes = 112.0 * 1048576.0;
  double bytes_per_voxel = 16.0;
  double bytes_per_gaussian = 160.0;
  [[nodiscard]] double need(std::size_t voxels, std::size_t gaussians) const {
    return base_bytes + bytes_per_voxel * static_cast<double>(voxels) +
           bytes_per_gaussian * static_cast<double>(gaussians);
  }
};

// The largest brick core for a stack of `shape` (x, y, z) whose `need(core)` is at
// most `bytes`: the stack's longest side, then shrinking by a quarter to multiples of
// 16 voxels, never below `smallest` (where it stops when nothing fits: the caller
// refuses).
[[nodiscard]] int largest_core(const std::array<int, 3>& shape, int smallest, double bytes,
                               const std::function<double(int)>& need);

// How a fit of a stack of `shape` (x, y, z) runs under gmf.max_memory.
struct FitPlanChoice {
  double max_memory = 0;       // bytes
  std::string memory_source;   // "gmf.max_memory" or "auto: half of 23.4 GiB of RAM"
  double whole_need = 0;       // the in-memory fit's need (FitMemoryModel)
  bool bricked = false;        // false: today's in-memory fit
  BrickPlan plan;         // when bricked
  double brick_need = 0;       // the largest brick's need
  bool for_ranks = false;      // bricks chosen to share among MPI ranks (the stack fits)
};
// The core edge (a multiple of 16 below `start`, never below `smallest`) that cuts
// a stack of `shape` into at least two bricks per rank of `ranks`: the work of an
// MPI launch on a stack that would fit one process (`start` when it already does).
[[nodiscard]] int core_for_ranks(const std::array<int, 3>& shape, int ranks, int start, int smallest);

// With `ranks` > 1 (an MPI launch) the fit is always bricked: without
// gmf.stream_brick_voxels, in bricks small enough for two per rank at least.
// Throws io::InputError("gmf.max_memory = X: ...") when not even the smallest brick
// fits (naming what it needs), or when gmf.max_memory does not parse.
[[nodiscard]] FitPlanChoice choose_fit_plan(const std::array<int, 3>& shape, const io::WorldFrame& frame,
                                            const GmfOptions& gmf, const FitMemoryModel& memory = {},
                                            int ranks = 1);

}  // namespace hisnegs::gmf
