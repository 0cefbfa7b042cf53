// SPDX-License-Identifier: Apache-2.0
// Non-inline parts of gaussian_mixture.hpp: array conversion, the brute-force
// reference evaluator and summary statistics. No file formats, no fitting.
#include "gmf/core/gaussian_mixture.hpp"

#include <algorithm>
#include <bit>
#include <limits>
#include <stdexcept>
#include <string>

namespace hisnegs::gmf {

std::array<float, kGaussianParamCount> to_array(const GaussianParams& g) {
  // kGaussianParamCount packed floats (static_asserts in the header), so a bit cast is exact.
  return std::bit_cast<std::array<float, kGaussianParamCount>>(g);
}

GaussianParams from_array(const std::array<float, kGaussianParamCount>& values) {
  return std::bit_cast<GaussianParams>(values);
}

double evaluate_mixture(const GaussianMixture& mixture, const Eigen::Vector3d& x_world) {
  return evaluate_mixture(mixture, x_world, std::numeric_limits<double>::infinity());
}

double evaluate_mixture(const GaussianMixture& mixture, const Eigen::Vector3d& x_world, double support) {
  double f = 0.0;
  for (const GaussianParams& g : mixture) {
    // dᵀ Σ⁻¹ d with Σ⁻¹ = R diag(1/s²) Rᵀ: rotate d into the Gaussian's frame and
    // divide by s, which avoids inverting Σ (ill-conditioned for flat Gaussians).
    const Eigen::Matrix3d r = rotation_matrix<double>(g);
    const Eigen::Vector3d d = x_world - Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2]);
    const Eigen::Vector3d local = (r.transpose() * d).cwiseQuotient(scales<double>(g));
    const double m = local.squaredNorm();
    if (m <= support) f += intensity<double>(g) * std::exp(-0.5 * m);
  }
  return f;
}

MixtureStats compute_stats(const GaussianMixture& mixture) {
  MixtureStats stats;
  stats.count = mixture.size();
  if (mixture.empty()) return stats;
  for (ParamRange& r : stats.params) {
    r.min = std::numeric_limits<double>::infinity();
    r.max = -std::numeric_limits<double>::infinity();
  }
  stats.intensity_min = std::numeric_limits<double>::infinity();
  stats.intensity_max = -std::numeric_limits<double>::infinity();
  for (const GaussianParams& g : mixture) {
    const std::array<float, kGaussianParamCount> v = to_array(g);
    for (std::size_t j = 0; j < kGaussianParamCount; ++j) {
      ParamRange& r = stats.params[j];
      r.min = std::min(r.min, static_cast<double>(v[j]));
      r.max = std::max(r.max, static_cast<double>(v[j]));
      r.mean += v[j];
    }
    const Eigen::Vector3d s = scales<double>(g);
    for (int i = 0; i < 3; ++i) stats.mean_scale[i] += s[i];
    const double ratio = s.maxCoeff() / s.minCoeff();
    stats.largest_axis_ratio = std::max(stats.largest_axis_ratio, ratio);
    stats.needles += ratio > kNeedleAxisRatio ? 1 : 0;
    const double a = intensity<double>(g);
    stats.intensity_min = std::min(stats.intensity_min, a);
    stats.intensity_max = std::max(stats.intensity_max, a);
    stats.intensity_mean += a;
  }
  const double n = static_cast<double>(mixture.size());
  for (ParamRange& r : stats.params) r.mean /= n;
  for (double& s : stats.mean_scale) s /= n;
  stats.intensity_mean /= n;
  return stats;
}

std::string_view parameter_group(std::size_t i) {
  constexpr std::array<std::string_view, kParamGroupCount> kNames = {"means", "log-scales", "rotation", "intensity"};
  return kNames[group_of(static_cast<int>(i % kGaussianParamCount))];
}

std::span<const float> flat_params(const GaussianMixture& mixture) {
  // GaussianParams is kGaussianParamCount packed floats (static_asserts in the header).
  return {reinterpret_cast<const float*>(mixture.data()), mixture.size() * kGaussianParamCount};
}

std::span<float> flat_params(GaussianMixture& mixture) {
  return {reinterpret_cast<float*>(mixture.data()), mixture.size() * kGaussianParamCount};
}

GaussianMixture mixture_from_flat(std::span<const float> params) {
  if (params.size() % kGaussianParamCount != 0) {
    throw std::invalid_argument("mixture_from_flat: " + std::to_string(params.size()) +
                                " values is not a whole number of Gaussians");
  }
  GaussianMixture mixture;
  mixture.resize(params.size() / kGaussianParamCount);
  std::copy(params.begin(), params.end(), flat_params(mixture).begin());
  return mixture;
}

}  // namespace hisnegs::gmf
