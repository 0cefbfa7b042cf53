// SPDX-License-Identifier: Apache-2.0
// Halos: Gaussians brighter than the stack they model, found by what they do to the
// stack, not by their shape. In a max- or sum-mixture f(μ_k) ≥ a_k, so a Gaussian
// whose peak a_k exceeds the normalized stack V at its centre by more than the
// stack's noise makes the model overshoot V there. In a hard MIP (what viewers and
// the ground truth show) those Gaussians are the dim halos and spikes around the
// neurites, whatever their axis ratio (gmf::kNeedleAxisRatio counts only needles).
#pragma once

#include <cstddef>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

// The smallest margin a Gaussian may exceed the stack by (a stack whose background
// is exactly 0 has no noise to measure): 2 % of the normalized range.
inline constexpr double kHaloMinNoise = 0.02;
// Background voxels for the noise estimate: below this share of the normalized
// range (the foreground level of the metrics, splat::kForegroundLevel).
inline constexpr double kHaloBackgroundLevel = 0.2;

// The stack's noise margin: 3 robust σ of its background voxels' deviation from
// their six neighbours' mean (1.4826 × the median absolute deviation, scaled by
// sqrt(6/7) to σ of one voxel), at least kHaloMinNoise. Throws
// std::invalid_argument for an empty volume.
[[nodiscard]] double stack_noise(const io::Volume& normalized);

struct HaloCount {
  std::size_t gaussians = 0;  // K
  std::size_t halos = 0;      // those with a_k > V(μ_k) + noise
  double noise = 0;           // the margin used
  std::vector<std::size_t> which;  // their indices, ascending
  [[nodiscard]] double share() const {
    return gaussians ? static_cast<double>(halos) / static_cast<double>(gaussians) : 0.0;
  }
};

// The Gaussians of `mixture` (world coordinates of `frame`) whose peak intensity
// exceeds the CONVENTIONS trilinear value of `normalized` at their centre (0 outside
// the box) by more than `noise`.
[[nodiscard]] HaloCount count_halos(const GaussianMixture& mixture, const io::Volume& normalized,
                                    const io::WorldFrame& frame, double noise);

}  // namespace hisnegs::gmf
