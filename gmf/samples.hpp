// SPDX-License-Identifier: Apache-2.0
// The points the GMF fit is measured on: every active voxel of a SparseGrid's
// `volume` grid (foreground + band) and of its `background` subsample, with
// world positions, target values and residual weights, grouped into cubic
// blocks of `block` voxels inside each OpenVDB leaf (block 8 = one leaf) so a
// block's samples form one residual block. Knows no Gaussians.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <vector>

#include "io/sparse_grid.hpp"

namespace hisnegs::gmf {

// ⌊a / b⌋ for b > 0 and any int a: block and leaf coordinates of voxel indices,
// which are negative for samples outside the stack.
[[nodiscard]] constexpr int floor_div(int a, int b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

struct SampleSet {
  // Structure of arrays, one entry per sample, blocks stored contiguously.
  std::vector<double> x, y, z;  // world position of the voxel centre
  std::vector<double> value;    // normalized intensity (the target)
  std::vector<double> weight;   // residual weight w: the loss is Σ w² (f(x) − value)²
  // Block b holds samples [block_begin[b], block_begin[b + 1]).
  std::vector<std::uint32_t> block_begin;
  std::vector<std::array<int, 3>> block_origin;  // index of the block's first voxel (multiples of `block`)
  int block = 8;                                 // block edge in voxels: 1, 2, 4 or 8
  std::int64_t foreground = 0;                   // samples from `volume` (weight 1)
  std::int64_t background = 0;                   // samples from `background`

  [[nodiscard]] std::size_t size() const { return value.size(); }
  [[nodiscard]] std::size_t blocks() const { return block_origin.size(); }
};

// Extracts the samples, grouped in blocks of `block` ∈ {1, 2, 4, 8} voxels.
// Background samples stand for 1 / background_fraction voxels each, so their
// weight is sqrt(background_weight / fraction): empty space counts in the loss
// as much as it would if every voxel were sampled.
// outside_voxels > 0 adds the shell outside the stack's box: for every foreground
// voxel on a face, that many voxels beyond it along the outward normal, value 0,
// weight 1, counted as background (their block origins may be negative or past
// the shape). The volume is 0 outside its box, as the ray-marched MIPs see it.
SampleSet extract_samples(const io::SparseGrid& grid, double background_weight, int block = 8, int outside_voxels = 0);

// The samples moved off the voxel centres: sample i moves by u ⊙ (voxel size), u
// uniform in [-jitter/2, jitter/2]³ (jitter in [0, 1]: 1 = anywhere in its voxel
// cell), and its target becomes the volume's CONVENTIONS trilinear value there
// (io::sample_trilinear: 0 outside the box, so the outside shell stays 0).
// Weights, blocks and counts are unchanged. u depends only on (seed, i), so the
// result does not depend on the thread count. jitter 0 returns a copy.
// Why: voxel centres alone leave a mixture free between them, and a fit uses that
// freedom (Gaussians thinner than a voxel, bright between centres) which every
// view at finer than voxel resolution shows (docs/benchmarks.md, "Sub-voxel
// samples"); the ray-marched MIPs see the trilinear interpolant everywhere.
[[nodiscard]] SampleSet jitter_samples(const SampleSet& samples, const io::Volume& volume, const io::WorldFrame& frame,
                                       double jitter, std::uint64_t seed);

// How far (world units, per axis) jitter_samples can move a sample from its voxel
// centre: jitter/2 of the voxel's edge on each axis. A block index padded by this
// (build_block_index's pad_world) reaches every moved sample a Gaussian reaches.
[[nodiscard]] Eigen::Vector3d jitter_reach(const io::WorldFrame& frame, double jitter);

}  // namespace hisnegs::gmf
