// SPDX-License-Identifier: Apache-2.0
// The double-precision splatting reference: its backward against central finite
// differences of its forward for every parameter kind, and the properties that
// define soft/hard MIP (centre pixel, culling, β -> ∞ limit).
#include "splat/splat_reference.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "tests/splat/splat_test_scenes.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::splat {
namespace {

using testing::make_splat_scene;

// L = Σ w_p I_p with fixed weights w: render_reference_backward(w) against Ridders'
// central differences of render_reference for every parameter, to 1e-5 relative.
void expect_backward_matches_fd(const std::vector<double>& params, const ViewParams<double>& view,
                                const SplatSettings& settings, const std::vector<double>& w) {
  const std::vector<double> grad = render_reference_backward(params, view, settings, w);
  auto loss = [&](const std::vector<double>& p) {
    const std::vector<double> img = render_reference(p, view, settings);
    double l = 0;
    for (std::size_t i = 0; i < img.size(); ++i) l += w[i] * img[i];
    return l;
  };
  for (std::size_t i = 0; i < params.size(); ++i) {
    double err = 0;
    const double fd = hisnegs::testing::ridders_derivative(
        [&](double x) {
          std::vector<double> p = params;
          p[i] = x;
          return loss(p);
        },
        params[i], 1e-3, &err);
    EXPECT_LT(std::abs(grad[i] - fd) / std::max(1e-3, std::abs(fd)), 1e-5)
        << "param " << i << " (kind " << i % 11 << "): analytic " << grad[i] << " fd " << fd;
  }
}

// L = Σ w_p I_p with fixed random weights w; its gradient is render_reference_backward(w).
TEST(SplatReference, BackwardMatchesFiniteDifferences) {
  for (std::uint64_t seed : {1u, 2u, 3u}) {
    const auto scene = make_splat_scene(5, seed);
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    SplatSettings settings;
    settings.beta = seed == 3 ? 8.0f : 50.0f;
    // A cutoff beyond every pixel: with δ = 16 a pixel entering or leaving a Gaussian's
    // support is a jump of a e^-8 that central differences would straddle.
    settings.cutoff = 1e6f;
    std::mt19937_64 rng(seed + 100);
    std::uniform_real_distribution<double> u(-1, 1);
    std::vector<double> w(static_cast<std::size_t>(view.width) * view.height);
    for (double& x : w) x = u(rng);
    SCOPED_TRACE("seed " + std::to_string(seed));
    expect_backward_matches_fd(scene.params, view, settings, w);
  }
}

// With a floor (the background's MIP: the image is max(splat, floor), the floor takes
// no gradient) the backward still matches finite differences, and a pixel no
// Gaussian reaches shows the floor itself.
TEST(SplatReference, BackwardWithAFloorMatchesFiniteDifferences) {
  const auto scene = make_splat_scene(5, 7);
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  std::mt19937_64 rng(17);
  std::uniform_real_distribution<double> u(-1, 1), level(0.0, 0.4);
  std::vector<float> floor(static_cast<std::size_t>(view.width) * view.height);
  for (float& b : floor) b = static_cast<float>(level(rng));
  floor[3] = 0.0f;  // no floor at this pixel
  for (const MipMode mode : {MipMode::kSoftmax, MipMode::kMax}) {
    SplatSettings settings;
    settings.mode = mode;
    settings.beta = 20.0f;
    settings.cutoff = 1e6f;
    settings.floor = floor;
    const std::vector<double> img = render_reference(scene.params, view, settings);
    SplatSettings bare = settings;
    bare.floor = {};
    const std::vector<double> without = render_reference(scene.params, view, bare);
    for (std::size_t i = 0; i < img.size(); ++i) EXPECT_DOUBLE_EQ(img[i], std::max<double>(without[i], floor[i])) << i;
  }
  // For the derivatives, every pixel's floor 0.1 above or below its soft MIP (or 0),
  // so no finite-difference step crosses the max's kink.
  SplatSettings settings;
  settings.beta = 20.0f;
  settings.cutoff = 1e6f;
  const std::vector<double> soft = render_reference(scene.params, view, settings);
  for (std::size_t i = 0; i < floor.size(); ++i) {
    floor[i] = i % 3 == 0 ? 0.0f : static_cast<float>(std::max(0.0, soft[i] + (i % 3 == 1 ? 0.1 : -0.1)));
  }
  settings.floor = floor;
  std::vector<double> w(floor.size());
  for (double& x : w) x = u(rng);
  expect_backward_matches_fd(scene.params, view, settings, w);
  // Far from every Gaussian (a scene of none): the image is the floor.
  const std::vector<double> empty = render_reference(std::vector<double>{}, view, settings);
  for (std::size_t i = 0; i < empty.size(); ++i) EXPECT_DOUBLE_EQ(empty[i], floor[i]) << i;
}

// The hard MIP's subgradient (each pixel's dL/dI to its largest term) against
// central differences, away from ties: only pixels whose two largest terms, and
// floor, differ by more than 0.05 carry a weight, and the step (1e-7) moves no term
// by that much, so no step crosses the max's kink.
TEST(SplatReference, HardBackwardMatchesFiniteDifferencesAwayFromTies) {
  for (std::uint64_t seed : {4u, 5u, 6u}) {
    const auto scene = make_splat_scene(6, seed);
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    const std::size_t pixels = static_cast<std::size_t>(view.width) * view.height;
    SplatSettings settings;
    settings.mode = MipMode::kMax;
    settings.cutoff = 1e6f;
    std::vector<float> floor(pixels, 0.0f);
    for (std::size_t i = 0; i < pixels; i += 4) floor[i] = 0.2f;
    settings.floor = floor;
    // Each pixel's gap between its largest and second-largest term (the floor one of them).
    std::vector<double> gap(pixels, 0.0);
    const std::size_t K = scene.params.size() / 11;
    std::vector<std::vector<double>> single(K);
    SplatSettings one = settings;
    one.floor = {};
    for (std::size_t k = 0; k < K; ++k) {
      single[k] = render_reference(std::span<const double>(scene.params).subspan(11 * k, 11), view, one);
    }
    std::mt19937_64 rng(seed + 200);
    std::uniform_real_distribution<double> u(-1, 1);
    std::vector<double> w(pixels, 0.0);
    int weighted = 0;
    for (std::size_t i = 0; i < pixels; ++i) {
      double top = floor[i], second = 0;
      for (std::size_t k = 0; k < K; ++k) {
        const double g = single[k][i];
        if (g > top) {
          second = top;
          top = g;
        } else if (g > second) {
          second = g;
        }
      }
      if (top - second > 0.05) w[i] = u(rng), ++weighted;
    }
    ASSERT_GT(weighted, static_cast<int>(pixels / 4)) << "seed " << seed;
    const std::vector<double> grad = render_reference_backward(scene.params, view, settings, w);
    auto loss = [&](const std::vector<double>& p) {
      const std::vector<double> img = render_reference(p, view, settings);
      double l = 0;
      for (std::size_t i = 0; i < img.size(); ++i) l += w[i] * img[i];
      return l;
    };
    for (std::size_t i = 0; i < scene.params.size(); ++i) {
      const double h = 1e-7;
      std::vector<double> plus = scene.params, minus = scene.params;
      plus[i] += h;
      minus[i] -= h;
      const double fd = (loss(plus) - loss(minus)) / (2 * h);
      EXPECT_LT(std::abs(grad[i] - fd) / std::max(1e-3, std::abs(fd)), 1e-5)
          << "seed " << seed << " param " << i << " (kind " << i % 11 << "): analytic " << grad[i] << " fd " << fd;
    }
  }
}

// One Gaussian's brightest pixel is the one its centre projects to, with value a.
TEST(SplatReference, GaussianLandsWhereItsCentreProjects) {
  auto scene = make_splat_scene(1, 7, 41, 33);
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  // Put the centre exactly on a pixel centre: solve for the world point on the ray of pixel (12, 20).
  const Eigen::Vector3d C = -scene.view.R_cam_from_world.transpose() * scene.view.t_cam_from_world;
  const Eigen::Vector3d dir = scene.view.R_cam_from_world.transpose() *
                              Eigen::Vector3d((12.5 - scene.K.cx) / scene.K.fx, (20.5 - scene.K.cy) / scene.K.fy, 1.0);
  const Eigen::Vector3d mu = C + 2.5 * dir;
  for (int a = 0; a < 3; ++a) scene.params[a] = mu[a];
  for (MipMode mode : {MipMode::kSoftmax, MipMode::kMax}) {
    SplatSettings settings;
    settings.mode = mode;
    const std::vector<double> img = render_reference(scene.params, view, settings);
    const auto best = std::max_element(img.begin(), img.end()) - img.begin();
    EXPECT_EQ(best % view.width, 12);
    EXPECT_EQ(best / view.width, 20);
    EXPECT_NEAR(img[best], 1.0 / (1.0 + std::exp(-scene.params[10])), 1e-9);  // one term: I = g = a at the centre
  }
}

// Behind the camera (or beyond far), and outside δ, a Gaussian contributes nothing.
TEST(SplatReference, CulledGaussiansContributeNothing) {
  auto scene = make_splat_scene(1, 8);
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  const Eigen::Vector3d C = -scene.view.R_cam_from_world.transpose() * scene.view.t_cam_from_world;
  const Eigen::Vector3d forward = scene.view.R_cam_from_world.row(2).transpose();
  SplatSettings settings;
  for (double depth : {-0.5, -0.001, 10.5}) {
    const Eigen::Vector3d mu = C + depth * forward;
    for (int a = 0; a < 3; ++a) scene.params[a] = mu[a];
    const std::vector<double> img = render_reference(scene.params, view, settings);
    EXPECT_EQ(*std::max_element(img.begin(), img.end()), 0.0) << "depth " << depth;
  }
  // In front: pixels beyond the δ ellipse are exactly 0, those inside are > 0.
  const Eigen::Vector3d mu = C + 2.5 * forward;
  for (int a = 0; a < 3; ++a) scene.params[a] = mu[a];
  settings.cutoff = 4.0f;
  const std::vector<double> img = render_reference(scene.params, view, settings);
  const Splat2D<double> s = project_gaussian(scene.params.data(), view, 4.0, 0.0);
  int inside = 0, outside = 0;
  for (int r = 0; r < view.height; ++r) {
    for (int c = 0; c < view.width; ++c) {
      const double q = splat_distance(s, c + 0.5, r + 0.5);
      const double v = img[static_cast<std::size_t>(r) * view.width + c];
      if (q <= 4.0) {
        ++inside;
        EXPECT_GT(v, 0.0);
      } else {
        ++outside;
        EXPECT_EQ(v, 0.0);
      }
    }
  }
  EXPECT_GT(inside, 4);
  EXPECT_GT(outside, 4);
}

// Soft-MIP tends to hard MIP as β grows, with the error falling monotonically.
TEST(SplatReference, SoftMipConvergesToHardMip) {
  const auto scene = make_splat_scene(12, 9);
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  SplatSettings hard;
  hard.mode = MipMode::kMax;
  const std::vector<double> target = render_reference(scene.params, view, hard);
  double previous = 1e300;
  for (float beta : {1.0f, 5.0f, 20.0f, 50.0f, 200.0f, 1000.0f, 5000.0f}) {
    SplatSettings soft;
    soft.beta = beta;
    const std::vector<double> img = render_reference(scene.params, view, soft);
    double err = 0;
    for (std::size_t i = 0; i < img.size(); ++i) {
      EXPECT_LE(img[i], target[i] + 1e-12);  // a weighted mean never exceeds the max
      err = std::max(err, target[i] - img[i]);
    }
    EXPECT_LT(err, previous) << "beta " << beta;
    previous = err;
  }
  EXPECT_LT(previous, 1e-3);
}

}  // namespace
}  // namespace hisnegs::splat
