// SPDX-License-Identifier: Apache-2.0
// gmf/density_ops: the Eq. 17 split (axis-aligned and rotated Gaussians, against
// an Eigen quaternion), longest_axis, isotropic_gaussian's clamp, the pruning
// threshold of bright_gaussians, keep_rows and keep_gaussians.
#include "gmf/core/density_ops.hpp"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"

namespace hisnegs::gmf {
namespace {

GaussianParams with_log_scales(float a, float b, float c) {
  GaussianParams g;
  g.log_scale = {a, b, c};
  return g;
}

// Children of `before` split with (offset, factor): means μ ± offset s_max r with
// r = column `axis` of R(q̂) from Eigen's quaternion, log-scales + ln factor (the
// same for both), rotation and logit unchanged. Float storage: 1e-6.
void expect_eq17(const GaussianParams& before, const GaussianParams& a, const GaussianParams& b, int axis,
                 double offset, double factor) {
  const Eigen::Quaterniond q(before.rotation[0], before.rotation[1], before.rotation[2], before.rotation[3]);
  const Eigen::Vector3d r = q.normalized().toRotationMatrix().col(axis);
  const double s_max = std::exp(static_cast<double>(before.log_scale[axis]));
  for (int d = 0; d < 3; ++d) {
    EXPECT_NEAR(a.mean[d], before.mean[d] + offset * s_max * r[d], 1e-6) << "axis " << d;
    EXPECT_NEAR(b.mean[d], before.mean[d] - offset * s_max * r[d], 1e-6) << "axis " << d;
    EXPECT_NEAR(a.log_scale[d], before.log_scale[d] + std::log(factor), 1e-6) << "axis " << d;
    EXPECT_EQ(b.log_scale[d], a.log_scale[d]) << "axis " << d;
  }
  EXPECT_EQ(a.rotation, before.rotation);
  EXPECT_EQ(b.rotation, before.rotation);
  EXPECT_EQ(a.intensity_logit, before.intensity_logit);
  EXPECT_EQ(b.intensity_logit, before.intensity_logit);
}

TEST(DensityOps, SplitMovesAnAxisAlignedGaussianAlongItsLongestAxis) {
  GaussianParams g = with_log_scales(std::log(0.1f), std::log(0.3f), std::log(0.2f));
  g.mean = {0.5f, -0.25f, 0.125f};
  g.intensity_logit = 1.5f;
  const GaussianParams before = g;
  const GaussianParams twin = split_gaussian(g, 0.5, 0.8);
  expect_eq17(before, g, twin, 1, 0.5, 0.8);
  // Along y only: μ_y ± 0.5 · 0.3.
  EXPECT_NEAR(g.mean[1], -0.25 + 0.15, 1e-6);
  EXPECT_NEAR(twin.mean[1], -0.25 - 0.15, 1e-6);
  EXPECT_EQ(g.mean[0], before.mean[0]);
  EXPECT_EQ(twin.mean[2], before.mean[2]);
}

// A rotated Gaussian with an unnormalized quaternion: the children move along the
// world direction of its longest principal axis, for other offsets and factors too.
TEST(DensityOps, SplitOfARotatedGaussianFollowsItsPrincipalAxis) {
  std::mt19937_64 rng(151);
  std::normal_distribution<double> n(0, 1);
  std::uniform_real_distribution<double> ls(-3, -1);
  for (int t = 0; t < 20; ++t) {
    GaussianParams g;
    for (int d = 0; d < 3; ++d) g.mean[d] = static_cast<float>(0.5 * n(rng));
    for (int d = 0; d < 3; ++d) g.log_scale[d] = static_cast<float>(ls(rng));
    for (int d = 0; d < 4; ++d) g.rotation[d] = static_cast<float>(2.5 * n(rng));  // |q| ≠ 1
    g.intensity_logit = static_cast<float>(n(rng));
    const GaussianParams before = g;
    const double offset = t % 2 ? 1.0 : 0.5, factor = t % 2 ? 0.6 : 0.8;
    const GaussianParams twin = split_gaussian(g, offset, factor);
    expect_eq17(before, g, twin, longest_axis(before), offset, factor);
  }
}

// Issue 33: the axis-ratio bound moves a needle's longest and shortest scales towards
// each other by the same factor and leaves Gaussians within the bound alone.
TEST(DensityOps, BoundAxisRatioTurnsNeedlesIntoShapesWithinTheRatio) {
  std::vector<double> p(3 * kGaussianParamCount, 0.0);
  const auto set = [&](int k, double a, double b, double c) {
    p[k * kGaussianParamCount + kLogScale0] = a;
    p[k * kGaussianParamCount + kLogScale0 + 1] = b;
    p[k * kGaussianParamCount + kLogScale0 + 2] = c;
  };
  set(0, std::log(0.5), std::log(0.01), std::log(0.02));  // ratio 50: a needle
  set(1, std::log(0.1), std::log(0.02), std::log(0.05));  // ratio 5
  set(2, std::log(1.0), std::log(0.001), std::log(0.5));  // ratio 1000, middle axis in range afterwards
  const std::vector<double> before = p;
  EXPECT_EQ(bound_axis_ratio(std::span<double>(p), 16.0), 2u);
  for (int k = 0; k < 3; ++k) {
    const double* s = &p[k * kGaussianParamCount + kLogScale0];
    const double lo = std::min({s[0], s[1], s[2]}), hi = std::max({s[0], s[1], s[2]});
    EXPECT_LE(hi - lo, std::log(16.0) + 1e-12) << k;
  }
  // The needle: both ends moved by the same factor sqrt(50 / 16).
  EXPECT_NEAR(p[kLogScale0] - before[kLogScale0], -0.5 * std::log(50.0 / 16.0), 1e-12);
  EXPECT_NEAR(p[kLogScale0 + 1] - before[kLogScale0 + 1], 0.5 * std::log(50.0 / 16.0), 1e-12);
  EXPECT_DOUBLE_EQ(p[kLogScale0 + 2], before[kLogScale0 + 2]);  // the middle one was inside the new range
  for (int i = 0; i < kGaussianParamCount; ++i) {
    EXPECT_EQ(p[kGaussianParamCount + i], before[kGaussianParamCount + i]) << i;  // within the bound: untouched
  }
  std::vector<float> f(before.begin(), before.end());
  EXPECT_EQ(bound_axis_ratio(std::span<float>(f), 16.0), 2u);
}

TEST(DensityOps, LongestAxisIsTheFirstLargestLogScale) {
  EXPECT_EQ(longest_axis(with_log_scales(1, 2, 3)), 2);
  EXPECT_EQ(longest_axis(with_log_scales(3, 2, 1)), 0);
  EXPECT_EQ(longest_axis(with_log_scales(-2, -1, -3)), 1);
  EXPECT_EQ(longest_axis(with_log_scales(1, 3, 3)), 1);
  EXPECT_EQ(longest_axis(with_log_scales(2, 2, 2)), 0);
}

// a = clamp(intensity, 0.02, 0.98) so the logit stays finite; log σ per axis,
// identity rotation, the given mean.
TEST(DensityOps, IsotropicGaussianClampsIntensityAndSetsLogSigma) {
  const Eigen::Vector3d mean(0.1, -0.2, 0.3), sigma(0.05, 0.1, 0.2);
  for (const auto& [given, a] : std::vector<std::pair<double, double>>{
           {0.5, 0.5}, {0.3, 0.3}, {0.0, 0.02}, {-1.0, 0.02}, {0.01, 0.02}, {0.99, 0.98}, {1.0, 0.98}, {5.0, 0.98}}) {
    const GaussianParams g = isotropic_gaussian(mean, sigma, given);
    EXPECT_NEAR(intensity(g), a, 1e-6) << "intensity " << given;
    EXPECT_TRUE(std::isfinite(g.intensity_logit));
    for (int d = 0; d < 3; ++d) {
      EXPECT_NEAR(g.log_scale[d], std::log(sigma[d]), 1e-6) << "axis " << d;
      EXPECT_EQ(g.mean[d], static_cast<float>(mean[d])) << "axis " << d;
    }
    EXPECT_EQ(g.rotation, (std::array<float, 4>{1, 0, 0, 0}));
  }
}

// Survivors of pruning: a = sigmoid(logit) >= min_intensity, ascending. A
// Gaussian exactly at the threshold stays; one just below goes.
TEST(DensityOps, BrightGaussiansKeepsThoseAtOrAboveTheThreshold) {
  const std::vector<float> logits = {-3.0f, 0.0f, 2.0f, 0.5f, 0.25f};
  std::vector<float> params(logits.size() * kGaussianParamCount, 0.7f);
  for (std::size_t k = 0; k < logits.size(); ++k) params[k * kGaussianParamCount + kLogit] = logits[k];
  const double at = sigmoid(static_cast<double>(0.5f));
  using Ids = std::vector<std::uint32_t>;
  EXPECT_EQ(bright_gaussians(params, at), (Ids{2, 3}));
  EXPECT_EQ(bright_gaussians(params, std::nextafter(at, 1.0)), (Ids{2}));
  EXPECT_EQ(bright_gaussians(params, 0.0), (Ids{0, 1, 2, 3, 4}));
  EXPECT_EQ(bright_gaussians(params, 0.99), Ids{});
  EXPECT_EQ(bright_gaussians(std::span<const float>(), 0.1), Ids{});
}

TEST(DensityOps, KeepRowsKeepsTheListedRowsInOrder) {
  std::vector<int> values(5 * 3);
  std::iota(values.begin(), values.end(), 0);  // row k holds 3k, 3k + 1, 3k + 2
  std::vector<int> kept_rows = values;
  const std::vector<std::uint32_t> kept = {1, 3, 4};
  keep_rows(kept_rows, kept, 3);
  EXPECT_EQ(kept_rows, (std::vector<int>{3, 4, 5, 9, 10, 11, 12, 13, 14}));

  std::vector<int> all = values;
  const std::vector<std::uint32_t> every = {0, 1, 2, 3, 4};
  keep_rows(all, every, 3);
  EXPECT_EQ(all, values);

  std::vector<int> none = values;
  keep_rows(none, std::span<const std::uint32_t>(), 3);
  EXPECT_TRUE(none.empty());

  std::vector<double> scalars = {0.5, 1.5, 2.5, 3.5};
  const std::vector<std::uint32_t> odd = {1, 3};
  keep_rows(scalars, odd);  // stride 1
  EXPECT_EQ(scalars, (std::vector<double>{1.5, 3.5}));
}

TEST(DensityOps, KeepGaussiansKeepsTheListedGaussiansInOrder) {
  GaussianMixture m;
  for (int k = 0; k < 5; ++k) {
    GaussianParams g;
    g.mean = {static_cast<float>(k), 0.5f * k, -1.0f * k};
    g.intensity_logit = 0.1f * k;
    m.push_back(g);
  }
  const GaussianMixture before = m;
  const std::vector<std::uint32_t> kept = {0, 2, 4};
  keep_gaussians(m, kept);
  ASSERT_EQ(m.size(), 3u);
  for (std::size_t j = 0; j < kept.size(); ++j) EXPECT_EQ(to_array(m[j]), to_array(before[kept[j]])) << j;
  keep_gaussians(m, std::span<const std::uint32_t>());
  EXPECT_TRUE(m.empty());
}

}  // namespace
}  // namespace hisnegs::gmf
