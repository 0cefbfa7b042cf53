// SPDX-License-Identifier: Apache-2.0
// Evaluation metrics against an independent computation on known image pairs:
// PSNR and MAE by hand, SSIM of an image with itself and under a constant offset,
// the summary statistics, and the comparison image's layout.
#include "splat/metrics.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace hisnegs::splat {
namespace {

TEST(Metrics, PsnrAndMaeOfAKnownPair) {
  // 16x12 target of 0.5; render differs by +0.1 on a quarter of the pixels.
  const int W = 16, H = 12;
  std::vector<float> target(W * H, 0.5f), render = target;
  for (int i = 0; i < W * H; i += 4) render[i] = 0.6f;
  const ViewMetrics m = image_metrics(render, target, W, H);
  const double mse = 0.25 * 0.01;  // a quarter of the pixels off by 0.1
  EXPECT_NEAR(m.psnr, 10 * std::log10(1 / mse), 1e-4);
  EXPECT_NEAR(m.mae, 0.025, 1e-7);
  EXPECT_LT(m.ssim, 1.0);
}

// A non-finite pixel is an error naming it (a NaN used to give PSNR +∞).
TEST(Metrics, ANonFinitePixelIsAnErrorNamingIt) {
  const int W = 16, H = 12;
  std::vector<float> target(W * H, 0.5f), render = target;
  render[7] = std::nanf("");
  try {
    (void)image_metrics(render, target, W, H);
    FAIL() << "a NaN pixel was measured";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("render pixel 7"), std::string::npos) << e.what();
  }
  render[7] = 0.5f;
  target[3] = INFINITY;
  EXPECT_THROW((void)image_metrics(render, target, W, H), std::invalid_argument);
}

// foreground_split: PSNR over the truth's foreground and background pixels and the
// background's share of the squared error, by hand.
TEST(Metrics, ForegroundSplitSeparatesTheErrorByTheTruth) {
  std::vector<float> target = {0.0f, 0.1f, 0.5f, 0.9f}, render = {0.1f, 0.1f, 0.5f, 0.7f};
  const ForegroundSplit s = foreground_split(render, target, 0.2);
  EXPECT_EQ(s.foreground, 2u);
  EXPECT_NEAR(s.psnr_fg, 10 * std::log10(1 / (0.04 / 2)), 1e-4);   // one pixel off by 0.2 of two
  EXPECT_NEAR(s.psnr_bg, 10 * std::log10(1 / (0.01 / 2)), 1e-4);   // one off by 0.1 of two
  EXPECT_NEAR(s.background_error_share, 0.01 / 0.05, 1e-6);
  EXPECT_TRUE(std::isinf(foreground_split(target, target, 0.2).psnr_fg));
}

TEST(Metrics, IdenticalImagesAreInfinitePsnrAndUnitSsim) {
  const int W = 20, H = 15;
  std::vector<float> img(W * H);
  for (int i = 0; i < W * H; ++i) img[i] = 0.5f + 0.4f * std::sin(0.37f * i);
  const ViewMetrics m = image_metrics(img, img, W, H);
  EXPECT_TRUE(std::isinf(m.psnr));
  EXPECT_EQ(m.mae, 0.0);
  EXPECT_NEAR(m.ssim, 1.0, 1e-12);
}

// SSIM of constant images x = a, y = b has no variance terms:
// (2ab + C1) / (a² + b² + C1) with C1 = (0.01)².
TEST(Metrics, SsimOfConstantImagesMatchesItsFormula) {
  const int W = 13, H = 13;
  const std::vector<float> a(W * H, 0.3f), b(W * H, 0.5f);
  const double C1 = 1e-4;
  const double expected = (2 * 0.3 * 0.5 + C1) / (0.09 + 0.25 + C1);
  EXPECT_NEAR(image_metrics(a, b, W, H).ssim, expected, 1e-6);
}

TEST(Metrics, SummaryIsMeanPopulationStdMinMax) {
  const std::vector<double> v = {1.0, 2.0, 3.0, 6.0};
  const MetricSummary s = summarize(v);
  EXPECT_DOUBLE_EQ(s.mean, 3.0);
  EXPECT_DOUBLE_EQ(s.std, std::sqrt((4.0 + 1.0 + 0.0 + 9.0) / 4.0));
  EXPECT_DOUBLE_EQ(s.min, 1.0);
  EXPECT_DOUBLE_EQ(s.max, 6.0);
}

TEST(Metrics, ComparisonImageIsTruthRenderError) {
  const int W = 4, H = 2;
  std::vector<float> target(W * H, 0.0f), render(W * H, 0.0f);
  target[0] = 1.0f;  // pixel (0, 0): truth white, render black, error saturated
  const io::Image8 img = comparison_image(target, render, W, H, 0.2f);
  ASSERT_EQ(img.width, 3 * W);
  ASSERT_EQ(img.height, H);
  ASSERT_EQ(img.channels, 3);
  EXPECT_EQ(img.pixels[0], 255);              // truth panel
  EXPECT_EQ(img.pixels[3 * W], 0);            // render panel
  EXPECT_EQ(img.pixels[3 * 2 * W + 0], 255);  // error panel: white at saturation
  EXPECT_EQ(img.pixels[3 * 2 * W + 2], 255);
  EXPECT_EQ(img.pixels[3 * (2 * W + 1)], 0);  // no error: black
  EXPECT_THROW(image_metrics(render, std::vector<float>(3), W, H), std::invalid_argument);
}

}  // namespace
}  // namespace hisnegs::splat
