// SPDX-License-Identifier: Apache-2.0
// split_gaussian, isotropic_gaussian, bright_gaussians, keep_gaussians.
#include "gmf/core/density_ops.hpp"

#include <algorithm>
#include <cmath>

#include "gmf/core/gaussian_math.hpp"

namespace hisnegs::gmf {

template <class T>
std::size_t bound_axis_ratio(std::span<T> params, double max_ratio) {
  const double limit = std::log(max_ratio);
  std::size_t changed = 0;
  for (std::size_t at = 0; at + kGaussianParamCount <= params.size(); at += kGaussianParamCount) {
    T* s = params.data() + at + kLogScale0;
    const double lo = std::min({double(s[0]), double(s[1]), double(s[2])});
    const double hi = std::max({double(s[0]), double(s[1]), double(s[2])});
    const double excess = hi - lo - limit;
    if (!(excess > 0.0)) continue;
    const double new_lo = lo + 0.5 * excess, new_hi = hi - 0.5 * excess;
    for (int i = 0; i < 3; ++i) s[i] = static_cast<T>(std::clamp(double(s[i]), new_lo, new_hi));
    ++changed;
  }
  return changed;
}
template std::size_t bound_axis_ratio<float>(std::span<float>, double);
template std::size_t bound_axis_ratio<double>(std::span<double>, double);

int longest_axis(const GaussianParams& g) {
  int axis = 0;
  for (int a = 1; a < 3; ++a) {
    if (g.log_scale[a] > g.log_scale[axis]) axis = a;
  }
  return axis;
}

GaussianParams split_gaussian(GaussianParams& g, double offset, double scale_factor) {
  const int axis = longest_axis(g);
  const double s_max = std::exp(static_cast<double>(g.log_scale[axis]));
  const GaussianFrame<double> f = frame_of(g);
  GaussianParams twin = g;
  for (int r = 0; r < 3; ++r) {
    const double step = offset * s_max * f.R[3 * r + axis];  // column `axis` of R
    g.mean[r] = static_cast<float>(g.mean[r] + step);
    twin.mean[r] = static_cast<float>(twin.mean[r] - step);
  }
  const double log_factor = std::log(scale_factor);
  for (int a = 0; a < 3; ++a) {
    g.log_scale[a] = static_cast<float>(g.log_scale[a] + log_factor);
    twin.log_scale[a] = g.log_scale[a];
  }
  return twin;
}

GaussianParams isotropic_gaussian(const Eigen::Vector3d& mean, const Eigen::Vector3d& sigma, double intensity) {
  GaussianParams g;
  for (int a = 0; a < 3; ++a) {
    g.mean[a] = static_cast<float>(mean[a]);
    g.log_scale[a] = static_cast<float>(std::log(sigma[a]));
  }
  g.rotation = {1.0f, 0.0f, 0.0f, 0.0f};
  const double a = std::clamp(intensity, 0.02, 0.98);
  g.intensity_logit = static_cast<float>(logit(a));
  return g;
}

std::vector<std::uint32_t> bright_gaussians(std::span<const float> params, double min_intensity) {
  std::vector<std::uint32_t> kept;
  const std::size_t K = params.size() / kGaussianParamCount;
  kept.reserve(K);
  for (std::size_t k = 0; k < K; ++k) {
    if (sigmoid(static_cast<double>(params[k * kGaussianParamCount + kLogit])) >= min_intensity) {
      kept.push_back(static_cast<std::uint32_t>(k));
    }
  }
  return kept;
}

void keep_gaussians(GaussianMixture& mixture, std::span<const std::uint32_t> kept) {
  std::size_t to = 0;
  for (const std::uint32_t k : kept) mixture[to++] = mixture[k];
  mixture.resize(to);
}

}  // namespace hisnegs::gmf
