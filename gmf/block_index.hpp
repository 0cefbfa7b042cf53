// SPDX-License-Identifier: Apache-2.0
// Which Gaussians can reach which sample block: a Gaussian touches a block when
// the axis-aligned box of its support {m <= δ} overlaps the block's voxel
// centres. Rebuilt between fit rounds as Gaussians move. Knows no solver.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/samples.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

struct BlockIndex {
  // Block b is reached by gaussians[begin[b] .. begin[b + 1]) (ascending ids).
  std::vector<std::uint32_t> begin;
  std::vector<std::uint32_t> gaussians;

  [[nodiscard]] std::span<const std::uint32_t> of(std::size_t block) const {
    return {gaussians.data() + begin[block], gaussians.data() + begin[block + 1]};
  }
};

// `cutoff` is δ (16 = 4σ). The support box is grown to half · scale_pad + pad_world
// per axis, so that a Gaussian whose scales may grow by `scale_pad` and whose mean
// may move by `pad_world` within a fit round (or whose samples may have moved by
// up to that much, gmf::jitter_reach) stays in every block it can reach.
// TBB-parallel over Gaussians.
BlockIndex build_block_index(const GaussianMixture& mixture, const SampleSet& samples, const io::WorldFrame& frame,
                             double cutoff, double scale_pad, const Eigen::Vector3d& pad_world);
// The same with one pad on every axis.
BlockIndex build_block_index(const GaussianMixture& mixture, const SampleSet& samples, const io::WorldFrame& frame,
                             double cutoff, double scale_pad = 1.0, double pad_world = 0.0);

// ½ Σ (w V)² over the samples of blocks no Gaussian reaches: their residuals are
// constant, so solvers leave them out and add this to the loss they report.
double unreached_loss(const SampleSet& samples, const BlockIndex& index);

}  // namespace hisnegs::gmf
