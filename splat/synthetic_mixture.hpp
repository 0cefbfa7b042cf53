// SPDX-License-Identifier: Apache-2.0
// Synthetic Gaussian mixtures shaped like the report's Table 3 (mean scales
// 0.031, 0.028, 0.089 world units) for the rendering benchmarks and tests:
// Gaussians strung along random smooth neurite-like paths inside the world box.
#pragma once

#include <cstdint>

#include "gmf/core/gaussian_mixture.hpp"

namespace hisnegs::splat {

struct SyntheticMixtureOptions {
  int gaussians = 50000;
  double mean_scale[3] = {0.031, 0.028, 0.089};  // per axis (before rotation), world units
  double log_scale_sigma = 0.35;                 // spread of each log-scale around log(mean) − σ²/2
  double box[3] = {0.9, 0.75, 0.55};             // means within ±box (world units)
  int paths = 40;                                // neurite-like paths the means follow
  std::uint64_t seed = 1;
};

gmf::GaussianMixture make_synthetic_mixture(const SyntheticMixtureOptions& options);

}  // namespace hisnegs::splat
