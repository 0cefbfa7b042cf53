// SPDX-License-Identifier: Apache-2.0
// Stage 2's 3D term: unlike the report's setting, training here
// always has the volume, so the loss can include the stage-1 residual of the
// model's own 3D value f (sum or softmax, gmf/core/aggregation.hpp) on a fresh batch of
// volume samples each step, and density control can drop Gaussians whose centre
// sits in empty space. The samples come from the caller (apps builds them from the
// fit's sparse grid); this file knows no OpenVDB and no Ceres.
#pragma once

#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include "gmf/core/aggregation.hpp"

namespace hisnegs::splat {

// Samples of the volume in blocks (a block's samples are close together, so the
// Gaussians reaching them are few): block b holds [block_begin[b], block_begin[b + 1]).
struct VolumeSamples {
  std::vector<float> x, y, z;    // world position
  std::vector<float> value;      // the normalized volume there (the target)
  std::vector<float> weight;     // residual weight w (the fit's: 1 foreground, larger for sparse background)
  std::vector<std::uint32_t> block_begin{0};

  [[nodiscard]] std::size_t size() const { return value.size(); }
  [[nodiscard]] std::size_t blocks() const { return block_begin.size() - 1; }
  // Throws std::invalid_argument for inconsistent sizes, an empty block or a non-finite value.
  void check() const;
};

// True when a world point lies in empty space (outside the foreground and its band).
using EmptySpaceTest = std::function<bool(const double world[3])>;

class VolumeTerm {
 public:
  // `model`: how the model's terms combine (the checkpoint's aggregation and β,
  // cutoff δ). `empty` may be null (then nothing counts as empty).
  VolumeTerm(VolumeSamples samples, const gmf::MixtureModel& model, EmptySpaceTest empty);

  // L = weight × Σ_j (w_j (f(x_j) − V_j))² / n over the n samples of `blocks`
  // (indices into the samples' blocks, repeats allowed); adds weight × ∂L/∂θ into
  // `grad` (kGaussianParamCount × K, aligned with `params`) and returns L. A term
  // counts where its Mahalanobis distance is <= the model's cutoff. TBB-parallel
  // over the blocks, combined in block order: deterministic.
  // `max`: the terms combine by their max (the hard share of training), not as the model says.
  double add(std::span<const float> params, std::span<const std::uint32_t> blocks, double weight,
             std::span<float> grad, bool max = false) const;

  // Whether Gaussian `p` (kGaussianParamCount values) has its centre in empty space.
  [[nodiscard]] bool centre_in_empty_space(const float* p) const;
  [[nodiscard]] std::size_t blocks() const { return samples_.blocks(); }
  [[nodiscard]] const VolumeSamples& samples() const { return samples_; }
  [[nodiscard]] const gmf::MixtureModel& model() const { return model_; }

 private:
  VolumeSamples samples_;
  gmf::MixtureModel model_;
  EmptySpaceTest empty_;
  std::vector<std::array<float, 6>> block_box_;  // per block: min x, y, z, max x, y, z of its samples
};

}  // namespace hisnegs::splat
