// SPDX-License-Identifier: Apache-2.0
// The local Ceres solver of the stage-1 fit ("brick-lm"): the Gaussians are
// partitioned into bricks (cubes of voxels holding their centres, halved where
// crowded); a brick's subproblem is its own Gaussians against the samples they
// reach, every other Gaussian's terms held fixed, solved by exact Levenberg-
// Marquardt. Bricks are coloured so that bricks of one colour share no sample, and
// a sweep solves the colours in turn, the bricks of a colour in parallel (block
// Gauss-Seidel). A brick solve is a pure function of its samples, its Gaussians
// and the fixed terms, so a sweep gives the same result for any thread count.
#pragma once

#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "gmf/core/aggregation.hpp"
#include "gmf/block_index.hpp"
#include "gmf/core/param_layout.hpp"
#include "gmf/samples.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

using ParamsD = std::array<double, kGaussianParamCount>;

struct BrickPartition {
  std::vector<std::uint32_t> brick_of;                // per Gaussian
  std::vector<std::vector<std::uint32_t>> gaussians;  // per brick, ascending ids
  std::vector<std::vector<std::uint32_t>> blocks;     // per brick: the sample blocks its Gaussians reach, ascending
  std::vector<std::vector<std::uint32_t>> colours;    // the bricks of each colour, ascending
};

// Bricks of `brick_voxels`³ voxels (index space of `frame`) holding the Gaussians'
// centres, each halved (down to 2 voxels) while it holds more than
// `max_gaussians`; coloured greedily (bricks in order, the smallest colour no
// neighbour has) so that no two bricks of a colour have a Gaussian reaching the same
// sample block of `index`. Deterministic.
[[nodiscard]] BrickPartition partition_into_bricks(std::span<const ParamsD> params, const BlockIndex& index,
                                                   const io::WorldFrame& frame, int brick_voxels, int max_gaussians);

struct BrickSweepOptions {
  MixtureModel model;
  int iterations = 8;  // LM iterations per brick
  // What a brick's residuals see of its Gaussians. A Gaussian enters a sample
  // block's residuals only where, at the start of the solve, a lower bound of its
  // √m over the block is at most √δ + reach_margin (in σ: it would have to move
  // further than that towards the block within the solve to reach it); blocks none
  // reaches are left out (their residuals are constant). The block index, padded
  // for a round's movement, lists many more: with all of them an op1 sweep took
  // 82 s, with these 28 s (docs/benchmarks.md).
  double reach_margin = 1.0;
  // Sample blocks are grouped, in order, into residual blocks while their
  // Gaussians number at most chunk_gaussians, so that Ceres forms the normal
  // equations block-sparse; solved with sparse Cholesky when `sparse` (and Ceres
  // has a sparse library), dense otherwise.
  int chunk_gaussians = 8;
  bool sparse = true;
  double seconds_left = 1e30;  // no brick starts after this, and none runs past it
};

struct BrickSweepStats {
  int bricks_solved = 0;
  int bricks_skipped = 0;       // left out because the time ran out
  std::int64_t iterations = 0;  // LM iterations over all bricks
};

// One sweep over every colour of `partition`: `params` (all Gaussians, double) are
// updated in place within [lower, upper] (flat, kGaussianParamCount per Gaussian;
// the quaternion stays on its manifold). `index` must list, for every sample block,
// every Gaussian that can reach it during the sweep (pad it for the bounds).
BrickSweepStats sweep_bricks(const SampleSet& samples, const BlockIndex& index, const BrickPartition& partition,
                             std::span<ParamsD> params, std::span<const double> lower, std::span<const double> upper,
                             const BrickSweepOptions& options);

}  // namespace hisnegs::gmf
