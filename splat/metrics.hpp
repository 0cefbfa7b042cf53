// SPDX-License-Identifier: Apache-2.0
// Image metrics of CONVENTIONS "Metrics" (PSNR of gmf/core/psnr.hpp, MAE, SSIM with the
// 11x11 σ 1.5 Gaussian window, data range 1) per view and their mean ± std over views, and the
// ground truth | render | |error| comparison image. No rendering here.
#pragma once

#include <span>
#include <vector>

#include "io/png.hpp"

namespace hisnegs::splat {

struct ViewMetrics {
  double psnr = 0, mae = 0, ssim = 0;  // PSNR in dB (infinite for identical images)
};

struct MetricSummary {
  double mean = 0, std = 0, min = 0, max = 0;  // std: population standard deviation
};

// Metrics of `render` against `target` (H x W each, row-major, values in [0, 1]).
// SSIM needs images of at least 11 x 11. Throws std::invalid_argument for a size mismatch.
// Throws std::invalid_argument for a non-finite pixel, naming it.
ViewMetrics image_metrics(std::span<const float> render, std::span<const float> target, int width, int height);

MetricSummary summarize(std::span<const double> values);

// Foreground pixels of a MIP: the ground truth at least this (normalized units;
// background.foreground_level's default). A dark background inflates a whole-image
// PSNR, so eval also gives the PSNR of these pixels alone, and of the others.
inline constexpr double kForegroundLevel = 0.2;

// The squared error of `render` split by the target's foreground (target >=
// `level`): PSNR over the foreground and over the background pixels (+∞ with no
// error; 0 where a part has no pixel), and the background's share of the whole
// squared error (0 with none): the halo measure, dim Gaussians shown where the
// truth is dark. Throws std::invalid_argument for a size mismatch.
struct ForegroundSplit {
  double psnr_fg = 0, psnr_bg = 0, background_error_share = 0;
  std::size_t foreground = 0;  // pixels
};
ForegroundSplit foreground_split(std::span<const float> render, std::span<const float> target,
                                 double level = kForegroundLevel);

// ground truth | render | |render − target| side by side (RGB, 3W x H): the first
// two grey, the error on a black-red-yellow-white ramp saturating at `error_max`.
io::Image8 comparison_image(std::span<const float> target, std::span<const float> render, int width, int height,
                            float error_max = 0.2f);

}  // namespace hisnegs::splat
