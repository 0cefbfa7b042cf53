// SPDX-License-Identifier: Apache-2.0
// The per-Gaussian operations of density control, shared by the stage-1 fit
// (gmf/density.hpp: which Gaussians, by residual error) and the stage-2 trainer
// (by screen-space gradient): the Eq. 17 split, a new isotropic Gaussian, and
// pruning faint Gaussians from every per-Gaussian array. No selection rules here.
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"

namespace hisnegs::gmf {

// Keeps every Gaussian of the flat parameters `params` (11 per Gaussian) within an
// axis ratio: where the largest scale is more than max_ratio times the smallest, the
// two are moved towards each other by the same factor (in log-scale, the nearest
// point with max − min = ln max_ratio; a middle axis outside that range is moved to
// its end), so that no Gaussian becomes a needle (a long thin shape fitted on
// noise). Returns how many Gaussians were changed. max_ratio > 1.
template <class T>
std::size_t bound_axis_ratio(std::span<T> params, double max_ratio);

// Index (0, 1, 2) of the largest log-scale (the first of equal ones).
[[nodiscard]] int longest_axis(const GaussianParams& g);

// Report Eq. 17: `g` and the returned twin become the two children at
// μ ± offset · s_max · r (r the unit principal axis of the largest scale s_max),
// log-scales + ln(scale_factor), the same rotation and intensity (a MIP takes the
// max, so intensity is not shared between them).
[[nodiscard]] GaussianParams split_gaussian(GaussianParams& g, double offset, double scale_factor);

// An axis-aligned Gaussian at `mean` with standard deviations `sigma` (world units)
// and peak a = clamp(intensity, 0.02, 0.98) (so its logit stays finite and trainable).
[[nodiscard]] GaussianParams isotropic_gaussian(const Eigen::Vector3d& mean, const Eigen::Vector3d& sigma,
                                                double intensity);

// Indices (ascending) of the Gaussians of `params` (kGaussianParamCount values
// each) whose a = sigmoid(logit) >= min_intensity: the survivors of pruning.
[[nodiscard]] std::vector<std::uint32_t> bright_gaussians(std::span<const float> params, double min_intensity);

// Keeps rows `kept` (ascending indices) of a per-Gaussian array of `stride` values
// per Gaussian, in order, and shrinks it to them.
template <class T>
void keep_rows(std::vector<T>& values, std::span<const std::uint32_t> kept, std::size_t stride = 1) {
  std::size_t to = 0;
  for (const std::uint32_t k : kept) {
    if (k != to) std::copy_n(values.begin() + k * stride, stride, values.begin() + to * stride);
    ++to;
  }
  values.resize(to * stride);
}

// keep_rows for a mixture.
void keep_gaussians(GaussianMixture& mixture, std::span<const std::uint32_t> kept);

}  // namespace hisnegs::gmf
