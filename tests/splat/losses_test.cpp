// SPDX-License-Identifier: Apache-2.0
// The training losses (report Eq. 11-16): every gradient against Ridders central
// differences of the double-precision path, SSIM and the soft histogram against
// brute-force definitions written out here, and each loss's defining properties.
#include "splat/losses.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numbers>
#include <random>
#include <stdexcept>
#include <utility>
#include <vector>

#include "gmf/core/gaussian_math.hpp"
#include "splat/splat_options.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::splat {
namespace {

constexpr int kW = 23;  // odd, non-square, and wider than SSIM's 11-pixel window
constexpr int kH = 19;

std::vector<double> random_image(int width, int height, std::uint64_t seed, double lo = 0.0, double hi = 1.0) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(lo, hi);
  std::vector<double> img(static_cast<std::size_t>(width) * height);
  for (double& v : img) v = u(rng);
  return img;
}

// `render` + noise of amplitude `amplitude`: a target that looks like the render, the
// regime training is in (independent images alone would only test far from the optimum).
std::vector<double> perturbed(const std::vector<double>& render, double amplitude, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-amplitude, amplitude);
  std::vector<double> out = render;
  for (double& v : out) v = std::clamp(v + u(rng), 0.0, 1.0);
  return out;
}

std::vector<float> to_floats(const std::vector<double>& v) { return {v.begin(), v.end()}; }
std::vector<double> to_doubles(const std::vector<float>& v) { return {v.begin(), v.end()}; }

// Compares `grad` with Ridders central differences of `loss` at every pixel of
// `render` (borders included). The analytic gradient is exact, and Ridders is good to
// ~1e-10, so 1e-5 relative leaves room only for real mistakes; components far below the
// largest (where a relative error means nothing) are measured against 1e-3 of it.
template <class Loss>
void expect_gradient_matches_fd(const Loss& loss, std::vector<double> render, const std::vector<double>& grad,
                                double h0) {
  ASSERT_EQ(grad.size(), render.size());
  double max_grad = 0;
  for (double g : grad) max_grad = std::max(max_grad, std::abs(g));
  ASSERT_GT(max_grad, 0.0);
  for (std::size_t i = 0; i < render.size(); ++i) {
    const double x0 = render[i];
    const double fd = hisnegs::testing::ridders_derivative(
        [&](double x) {
          render[i] = x;
          const double l = loss(render);
          render[i] = x0;
          return l;
        },
        x0, h0);
    const double scale = std::max(std::abs(fd), 1e-3 * max_grad);
    EXPECT_LT(std::abs(grad[i] - fd) / scale, 1e-5)
        << "pixel " << i << " (row " << i / kW << ", column " << i % kW << "): analytic " << grad[i] << " fd " << fd;
  }
}

// ------------------------------------------------------------------ Eq. 11

// w = 1 + (5 − 1) g = (5, 1, 3, 2); d = p − g = (−0.5, 0.25, 0.5, −0.25);
// L = (5·0.25 + 1·0.0625 + 3·0.25 + 2·0.0625) / 4 = 2.1875 / 4; ∂L/∂p = 2 w d / 4.
TEST(LossWeightedMse, HandComputedTwoByTwo) {
  const std::vector<double> render = {0.5, 0.25, 1.0, 0.0};
  const std::vector<double> target = {1.0, 0.0, 0.5, 0.25};
  std::vector<double> grad(4, 0.0);
  const double loss = weighted_mse(render, target, 2, 2, 5.0, 2.0, grad);
  EXPECT_DOUBLE_EQ(loss, 2.1875 / 4);
  const double expected[4] = {2 * 5 * -0.5 / 4, 2 * 1 * 0.25 / 4, 2 * 3 * 0.5 / 4, 2 * 2 * -0.25 / 4};
  for (int i = 0; i < 4; ++i) EXPECT_DOUBLE_EQ(grad[i], 2.0 * expected[i]) << i;  // weight 2
}

TEST(LossWeightedMse, GradientMatchesFiniteDifferences) {
  const auto render = random_image(kW, kH, 1), target = random_image(kW, kH, 2);
  std::vector<double> grad(render.size(), 0.0);
  weighted_mse(render, target, kW, kH, 5.0, 1.0, grad);
  expect_gradient_matches_fd(
      [&](const std::vector<double>& r) { return weighted_mse(r, target, kW, kH, 5.0, 1.0, {}); }, render, grad, 1e-2);
}

// ------------------------------------------------------------------ Eq. 12

// The definition, written out: 2D Gaussian window (σ 1.5, 11 taps, normalised), variances
// and covariance as weighted sums of centred products, mean over the pixels >= 5 from
// every border (scikit-image's crop). Nothing shared with the separable implementation.
double brute_force_mean_ssim(const std::vector<double>& x, const std::vector<double>& y, int width, int height) {
  double g[11], gsum = 0;
  for (int k = 0; k < 11; ++k) gsum += g[k] = std::exp(-(k - 5) * (k - 5) / (2 * 1.5 * 1.5));
  double sum = 0;
  int count = 0;
  for (int r = 5; r < height - 5; ++r)
    for (int c = 5; c < width - 5; ++c) {
      auto window = [&](auto&& f) {
        double s = 0;
        for (int i = -5; i <= 5; ++i)
          for (int j = -5; j <= 5; ++j) s += g[i + 5] * g[j + 5] / (gsum * gsum) * f((r + i) * width + (c + j));
        return s;
      };
      const double mx = window([&](int p) { return x[p]; }), my = window([&](int p) { return y[p]; });
      const double vx = window([&](int p) { return (x[p] - mx) * (x[p] - mx); });
      const double vy = window([&](int p) { return (y[p] - my) * (y[p] - my); });
      const double vxy = window([&](int p) { return (x[p] - mx) * (y[p] - my); });
      const double C1 = 1e-4, C2 = 9e-4;
      sum += (2 * mx * my + C1) * (2 * vxy + C2) / ((mx * mx + my * my + C1) * (vx + vy + C2));
      ++count;
    }
  return sum / count;
}

TEST(LossSsim, ImageWithItselfIsOne) {
  const auto img = random_image(kW, kH, 3);
  LossWorkspace ws;
  std::vector<double> grad(img.size(), 0.0);
  EXPECT_NEAR(ssim_loss(img, img, kW, kH, 1.0, grad, ws), 0.0, 1e-14);
  for (double g : grad) EXPECT_NEAR(g, 0.0, 1e-13);  // S = 1 is the maximum: a stationary point
}

// Sizes: the test image, and one spanning many row blocks of the parallel loops.
constexpr int kSizes[2][2] = {{kW, kH}, {200, 70}};

TEST(LossSsim, MatchesBruteForceDefinition) {
  for (const auto& [width, height] : kSizes) {
    const auto x = random_image(width, height, 4), y = perturbed(x, 0.3, 5);
    LossWorkspace ws;
    const double expected = brute_force_mean_ssim(x, y, width, height);
    EXPECT_GT(expected, 0.05);  // a pair neither identical nor unrelated
    EXPECT_LT(expected, 0.95);
    EXPECT_NEAR(1.0 - ssim_loss(x, y, width, height, 1.0, {}, ws), expected, 1e-12);
    // The float overload on the same (float-rounded) pixels: it accumulates in double too.
    const auto xf = to_floats(x), yf = to_floats(y);
    EXPECT_NEAR(1.0 - ssim_loss(xf, yf, width, height, 1.0, {}, ws),
                brute_force_mean_ssim(to_doubles(xf), to_doubles(yf), width, height), 1e-6);
  }
}

TEST(LossSsim, IsSymmetric) {
  const auto x = random_image(kW, kH, 6), y = random_image(kW, kH, 7);
  LossWorkspace ws;
  EXPECT_NEAR(ssim_loss(x, y, kW, kH, 1.0, {}, ws), ssim_loss(y, x, kW, kH, 1.0, {}, ws), 1e-15);
}

TEST(LossSsim, GradientMatchesFiniteDifferences) {
  const auto render = random_image(kW, kH, 8);
  for (const auto& target : {random_image(kW, kH, 9), perturbed(render, 0.05, 10)}) {
    LossWorkspace ws;
    std::vector<double> grad(render.size(), 0.0);
    ssim_loss(render, target, kW, kH, 1.0, grad, ws);
    expect_gradient_matches_fd([&](const std::vector<double>& r) { return ssim_loss(r, target, kW, kH, 1.0, {}, ws); },
                               render, grad, 1e-3);
  }
}

TEST(LossSsim, RejectsImagesSmallerThanTheWindow) {
  const auto img = random_image(10, 30, 11);
  LossWorkspace ws;
  EXPECT_THROW(ssim_loss(img, img, 10, 30, 1.0, {}, ws), std::invalid_argument);
}

// ------------------------------------------------------------------ Eq. 13

// Sobel written out pixel by pixel with replicated borders.
double brute_force_edge(const std::vector<double>& p, const std::vector<double>& g, int width, int height) {
  const int kx[3][3] = {{-1, 0, 1}, {-2, 0, 2}, {-1, 0, 1}};
  double sum = 0;
  for (int r = 0; r < height; ++r)
    for (int c = 0; c < width; ++c) {
      double gx = 0, gy = 0;
      for (int i = -1; i <= 1; ++i)
        for (int j = -1; j <= 1; ++j) {
          const int idx = std::clamp(r + i, 0, height - 1) * width + std::clamp(c + j, 0, width - 1);
          const double d = p[idx] - g[idx];
          gx += kx[i + 1][j + 1] * d;
          gy += kx[j + 1][i + 1] * d;
        }
      sum += gx * gx + gy * gy;
    }
  return sum / (width * height);
}

TEST(LossEdge, MatchesBruteForceSobel) {
  for (const auto& [width, height] : kSizes) {
    const auto p = random_image(width, height, 12), g = random_image(width, height, 13);
    LossWorkspace ws;
    EXPECT_NEAR(edge_loss(p, g, width, height, 1.0, {}, ws), brute_force_edge(p, g, width, height), 1e-12);
  }
}

// One-pixel-wide images: every neighbour is clamped onto the pixel itself.
TEST(LossEdge, MatchesBruteForceSobelOnDegenerateSizes) {
  for (const auto& [width, height] : {std::pair{1, 7}, std::pair{9, 1}, std::pair{1, 1}, std::pair{2, 2}}) {
    const auto p = random_image(width, height, 38), g = random_image(width, height, 39);
    LossWorkspace ws;
    EXPECT_NEAR(edge_loss(p, g, width, height, 1.0, {}, ws), brute_force_edge(p, g, width, height), 1e-12)
        << width << "x" << height;
  }
}

// With replicated borders a constant offset has no edges anywhere, the border included.
TEST(LossEdge, ConstantOffsetCostsNothing) {
  const auto g = random_image(kW, kH, 14);
  auto p = g;
  for (double& v : p) v += 0.25;
  LossWorkspace ws;
  std::vector<double> grad(p.size(), 0.0);
  EXPECT_NEAR(edge_loss(p, g, kW, kH, 1.0, grad, ws), 0.0, 1e-24);
  for (double v : grad) EXPECT_NEAR(v, 0.0, 1e-14);
}

TEST(LossEdge, GradientMatchesFiniteDifferences) {
  const auto render = random_image(kW, kH, 15), target = random_image(kW, kH, 16);
  LossWorkspace ws;
  std::vector<double> grad(render.size(), 0.0);
  edge_loss(render, target, kW, kH, 1.0, grad, ws);
  expect_gradient_matches_fd([&](const std::vector<double>& r) { return edge_loss(r, target, kW, kH, 1.0, {}, ws); },
                             render, grad, 1e-2);
}

// ------------------------------------------------------------------ Eq. 14

// The soft-histogram KL with one exp() per pixel and bin and no truncation.
double brute_force_kl(const std::vector<double>& p, const std::vector<double>& g, const SoftHistogramOptions& o) {
  auto hist = [&](const std::vector<double>& img) {
    std::vector<double> h(o.bins, 0.0);
    const double delta = 1.0 / o.bins;
    for (double x : img)
      for (int b = 0; b < o.bins; ++b) {
        const double z = ((b + 0.5) * delta - x) / o.bandwidth;
        h[b] += delta / (std::sqrt(2 * std::numbers::pi) * o.bandwidth) * std::exp(-0.5 * z * z) / img.size();
      }
    double total = 0;
    for (double& v : h) total += v += o.epsilon;
    for (double& v : h) v /= total;
    return h;
  };
  const auto hp = hist(p), hg = hist(g);
  double kl = 0;
  for (int b = 0; b < o.bins; ++b) kl += hp[b] * std::log(hp[b] / hg[b]);
  return kl;
}

// Identical images give bitwise-identical histograms: KL exactly 0, and its gradient 0
// (the minimum). No ε tolerance is needed for that.
TEST(LossIntensityKl, ZeroForIdenticalImages) {
  const auto img = random_image(kW, kH, 17);
  LossWorkspace ws;
  std::vector<double> grad(img.size(), 0.0);
  EXPECT_EQ(intensity_kl_loss(img, img, kW, kH, {}, 1.0, grad, ws), 0.0);
  for (double v : grad) EXPECT_EQ(v, 0.0);
}

TEST(LossIntensityKl, PositiveForDifferentHistograms) {
  const auto dark = random_image(kW, kH, 18, 0.0, 0.5), bright = random_image(kW, kH, 19, 0.3, 1.0);
  LossWorkspace ws;
  EXPECT_GT(intensity_kl_loss(dark, bright, kW, kH, {}, 1.0, {}, ws), 0.1);
  EXPECT_GT(intensity_kl_loss(bright, dark, kW, kH, {}, 1.0, {}, ws), 0.1);
}

// A histogram forgets where pixels are: a permuted image has the same one, up to the
// order of summation (rounding, ~1e-16 per bin).
TEST(LossIntensityKl, BlindToPixelOrder) {
  const auto img = random_image(kW, kH, 20);
  auto shuffled = img;
  std::shuffle(shuffled.begin(), shuffled.end(), std::mt19937_64(21));
  LossWorkspace ws;
  EXPECT_NEAR(intensity_kl_loss(shuffled, img, kW, kH, {}, 1.0, {}, ws), 0.0, 1e-13);
}

// The recurrence over bins and its cut-off at 1e-17 ε reproduce the direct sum; a few
// pixels lie outside [0, 1], as soft-MIP renders can.
TEST(LossIntensityKl, MatchesBruteForceDefinition) {
  for (const auto& [width, height] : kSizes) {  // 200 x 70 spans several pixel blocks
    const auto p = random_image(width, height, 22, -0.05, 1.1);
    const auto g = random_image(width, height, 23);
    LossWorkspace ws;
    for (const SoftHistogramOptions& o : {SoftHistogramOptions{}, SoftHistogramOptions{16, 0.1, 1e-8}}) {
      const double expected = brute_force_kl(p, g, o);
      EXPECT_GT(expected, 1e-3);
      EXPECT_NEAR(intensity_kl_loss(p, g, width, height, o, 1.0, {}, ws), expected, 1e-12 * std::max(1.0, expected));
    }
  }
}

TEST(LossIntensityKl, GradientMatchesFiniteDifferences) {
  const auto render = random_image(kW, kH, 24, -0.05, 1.1), target = random_image(kW, kH, 25);
  for (const SoftHistogramOptions& o : {SoftHistogramOptions{}, SoftHistogramOptions{16, 0.1, 1e-8}}) {
    LossWorkspace ws;
    std::vector<double> grad(render.size(), 0.0);
    intensity_kl_loss(render, target, kW, kH, o, 1.0, grad, ws);
    // h0 a tenth of the default kernel width (1/64).
    expect_gradient_matches_fd(
        [&](const std::vector<double>& r) { return intensity_kl_loss(r, target, kW, kH, o, 1.0, {}, ws); }, render,
        grad, 1.5e-3);
  }
}

TEST(LossIntensityKl, RejectsNonFinitePixels) {
  auto render = random_image(kW, kH, 35);
  const auto target = render;
  render[100] = std::numeric_limits<double>::quiet_NaN();
  LossWorkspace ws;
  EXPECT_THROW(intensity_kl_loss(render, target, kW, kH, {}, 1.0, {}, ws), std::invalid_argument);
}

TEST(LossIntensityKl, RejectsInvalidHistogramOptions) {
  const auto img = random_image(kW, kH, 26);
  LossWorkspace ws;
  EXPECT_THROW(intensity_kl_loss(img, img, kW, kH, SoftHistogramOptions{1, 0.1, 1e-6}, 1.0, {}, ws),
               std::invalid_argument);
  EXPECT_THROW(intensity_kl_loss(img, img, kW, kH, SoftHistogramOptions{64, 0.0, 1e-6}, 1.0, {}, ws),
               std::invalid_argument);
}

// ------------------------------------------------------------------ Eq. 15

// K Gaussians whose 3 scales are `scales[3k .. 3k+2]`, other parameters arbitrary.
std::vector<double> params_with_scales(const std::vector<double>& scales) {
  std::vector<double> params((scales.size() / 3) * gmf::kGaussianParamCount, 0.3);
  for (std::size_t i = 0; i < scales.size(); ++i)
    params[(i / 3) * gmf::kGaussianParamCount + gmf::kLogScale0 + i % 3] = std::log(scales[i]);
  return params;
}

TEST(LossScaleRegularizer, ZeroInsideTheRange) {
  const auto params = params_with_scales({0.0011, 0.02, 0.49, 0.3, 0.3, 0.3});
  std::vector<double> grad(params.size(), 0.0);
  EXPECT_EQ(scale_regularizer(params, 0.001, 0.5, 1.0, grad), 0.0);
  for (double g : grad) EXPECT_EQ(g, 0.0);
}

// Σ (s_min − s) below plus Σ (s − s_max) above: (0.001 − 0.0004) + (0.8 − 0.5) + (2 − 0.5).
TEST(LossScaleRegularizer, PositiveOutsideTheRange) {
  const auto params = params_with_scales({0.0004, 0.01, 0.8, 0.1, 2.0, 0.1});
  std::vector<double> grad(params.size(), 0.0);
  EXPECT_NEAR(scale_regularizer(params, 0.001, 0.5, 3.0, grad), 0.0006 + 0.3 + 1.5, 1e-12);
  EXPECT_NEAR(grad[gmf::kLogScale0], -3.0 * 0.0004, 1e-15);  // pushes a too small scale up
  EXPECT_NEAR(grad[gmf::kLogScale2], 3.0 * 0.8, 1e-12);      // and a too large one down
}

TEST(LossScaleRegularizer, GradientMatchesFiniteDifferences) {
  // Scales at least e^0.3 away from the kinks, so no difference straddles one.
  auto params = params_with_scales({0.0003, 0.0006, 0.01, 0.1, 0.8, 1.5, 0.0002, 0.2, 4.0});
  std::vector<double> grad(params.size(), 0.0);
  scale_regularizer(params, 0.001, 0.5, 0.7, grad);
  for (std::size_t i = 0; i < params.size(); ++i) {
    const double x0 = params[i];
    const double fd = hisnegs::testing::ridders_derivative(
        [&](double x) {
          params[i] = x;
          const double l = 0.7 * scale_regularizer(params, 0.001, 0.5, 1.0, {});
          params[i] = x0;
          return l;
        },
        x0, 1e-2);
    EXPECT_NEAR(grad[i], fd, 1e-5 * std::max(std::abs(fd), 1e-3)) << "param " << i;
  }
}

// ------------------------------------------------------------------ Eq. 16

TEST(LossCombined, SumsTheWeightedTermsAndTheirGradients) {
  const auto render = to_floats(random_image(kW, kH, 27)), target = to_floats(random_image(kW, kH, 28));
  TrainOptions train;
  train.lambda_intensity = 0.5;  // big enough that a missing term would show
  const ImageLossWeights w = image_loss_weights(train);
  LossWorkspace ws;
  std::vector<float> grad(render.size(), 0.0f);
  const ImageLossTerms terms = combined_image_loss(render, target, kW, kH, w, grad, ws);

  std::vector<float> expected_grad(render.size(), 0.0f);
  const double wmse = weighted_mse(render, target, kW, kH, train.foreground_weight, 1.0, expected_grad);
  const double ssim = ssim_loss(render, target, kW, kH, train.lambda_ssim, expected_grad, ws);
  const double edge = edge_loss(render, target, kW, kH, train.lambda_edge, expected_grad, ws);
  const double kl = intensity_kl_loss(render, target, kW, kH, {}, 0.5, expected_grad, ws);
  EXPECT_DOUBLE_EQ(terms.wmse, wmse);
  EXPECT_DOUBLE_EQ(terms.ssim, ssim);
  EXPECT_DOUBLE_EQ(terms.edge, edge);
  EXPECT_DOUBLE_EQ(terms.intensity, kl);
  EXPECT_NEAR(terms.total, wmse + train.lambda_ssim * ssim + train.lambda_edge * edge + 0.5 * kl, 1e-12);
  for (std::size_t i = 0; i < grad.size(); ++i) EXPECT_FLOAT_EQ(grad[i], expected_grad[i]) << i;
}

// The registry holds each image loss once, in the order combined_image_loss adds
// them; each entry's double function is that loss with its gradient (the finite-
// difference checks above cover the functions themselves).
TEST(LossCombined, TheRegistryHoldsEachImageLossOnce) {
  const auto render = random_image(kW, kH, 31), target = random_image(kW, kH, 32);
  std::vector<std::string> names;
  for (const ImageLossEntry& loss : image_losses()) names.emplace_back(loss.name);
  EXPECT_EQ(names, (std::vector<std::string>{"wmse", "ssim", "edge", "intensity"}));
  ImageLossWeights w;
  w.foreground_weight = 3.0;
  LossWorkspace ws;
  for (const ImageLossEntry& loss : image_losses()) {
    std::vector<double> grad(render.size(), 0.0), alone(render.size(), 0.0);
    const double value = loss.of_double(render, target, kW, kH, w, 0.5, grad, ws);
    ImageLossWeights only;
    only.wmse = 0.0;
    only.foreground_weight = 3.0;
    only.*loss.weight = 0.5;
    const ImageLossTerms terms = combined_image_loss(render, target, kW, kH, only, alone, ws);
    EXPECT_DOUBLE_EQ(terms.*loss.value, value) << loss.name;
    EXPECT_DOUBLE_EQ(terms.total, 0.5 * value) << loss.name;
    for (std::size_t i = 0; i < grad.size(); ++i) ASSERT_EQ(grad[i], alone[i]) << loss.name << " " << i;
  }
}

TEST(LossCombined, TermsOfWeightZeroAreNotEvaluated) {
  const auto render = random_image(kW, kH, 29), target = random_image(kW, kH, 30);
  LossWorkspace ws;
  const ImageLossTerms terms = combined_image_loss(render, target, kW, kH, ImageLossWeights{}, {}, ws);
  EXPECT_DOUBLE_EQ(terms.wmse, weighted_mse(render, target, kW, kH, 1.0, 1.0, {}));  // plain MSE
  EXPECT_DOUBLE_EQ(terms.total, terms.wmse);
  EXPECT_TRUE(std::isnan(terms.ssim));
  EXPECT_TRUE(std::isnan(terms.edge));
  EXPECT_TRUE(std::isnan(terms.intensity));
}

// The float overloads the trainer calls against the double reference on the same
// (float) pixels at the trainer's image size. Both accumulate in double, so only the
// final rounding of each gradient to float differs: 1e-6 of the largest component.
TEST(LossCombined, FloatMatchesDoubleReference) {
  constexpr int kSide = 64;
  const auto render = to_floats(random_image(kSide, kSide, 31));
  const auto target = to_floats(perturbed(to_doubles(render), 0.2, 32));
  TrainOptions train;
  const ImageLossWeights w = image_loss_weights(train);
  LossWorkspace ws;
  std::vector<float> grad_f(render.size(), 0.0f);
  std::vector<double> grad_d(render.size(), 0.0);
  const ImageLossTerms tf = combined_image_loss(render, target, kSide, kSide, w, grad_f, ws);
  const ImageLossTerms td = combined_image_loss(to_doubles(render), to_doubles(target), kSide, kSide, w, grad_d, ws);
  EXPECT_DOUBLE_EQ(tf.total, td.total);
  double max_grad = 0;
  for (double g : grad_d) max_grad = std::max(max_grad, std::abs(g));
  for (std::size_t i = 0; i < grad_d.size(); ++i) EXPECT_NEAR(grad_f[i], grad_d[i], 1e-6 * max_grad) << i;
}

// Fixed blocks with partial sums added in order: one thread and many give the same
// bits. 200 x 70 spans several row blocks (8 rows) and pixel blocks (4096 pixels).
TEST(LossCombined, SameBitsWhateverTheThreadCount) {
  constexpr int kWide = 200, kTall = 70;
  const auto render = to_floats(random_image(kWide, kTall, 36));
  const auto target = to_floats(perturbed(to_doubles(render), 0.3, 37));
  TrainOptions train;
  const ImageLossWeights w = image_loss_weights(train);
  auto run = [&](std::vector<float>& grad) {
    LossWorkspace ws;
    grad.assign(render.size(), 0.0f);
    return combined_image_loss(render, target, kWide, kTall, w, grad, ws).total;
  };
  std::vector<float> grad_many, grad_one;
  const double total_many = run(grad_many);
  double total_one = 0;
  {
    tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
    total_one = run(grad_one);
  }
  EXPECT_EQ(total_many, total_one);
  EXPECT_EQ(grad_many, grad_one);
}

TEST(LossCombined, RejectsMismatchedSizes) {
  const auto render = random_image(kW, kH, 33);
  const auto target = random_image(kW, kH - 1, 34);
  LossWorkspace ws;
  TrainOptions train;
  EXPECT_THROW(combined_image_loss(render, target, kW, kH, image_loss_weights(train), {}, ws), std::invalid_argument);
}

}  // namespace
}  // namespace hisnegs::splat
