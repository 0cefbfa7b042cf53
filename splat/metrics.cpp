// SPDX-License-Identifier: Apache-2.0
// image_metrics (PSNR through gmf/core/psnr.hpp, MAE directly, SSIM through
// losses.hpp's scikit-image-equivalent ssim_loss), summarize, comparison_image.
#include "splat/metrics.hpp"

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>

#include "gmf/core/psnr.hpp"
#include "splat/losses.hpp"

namespace hisnegs::splat {

ViewMetrics image_metrics(std::span<const float> render, std::span<const float> target, int width, int height) {
  const std::size_t n = static_cast<std::size_t>(width) * height;
  if (render.size() != n || target.size() != n || n == 0) {
    throw std::invalid_argument("image_metrics: images of " + std::to_string(render.size()) + " and " +
                                std::to_string(target.size()) + " pixels for " + std::to_string(width) + "x" +
                                std::to_string(height));
  }
  // A non-finite pixel has no error to measure: PSNR came out +∞ for one NaN.
  for (const auto& [image, name] : {std::pair{render, "render"}, std::pair{target, "target"}}) {
    const auto bad = std::find_if(image.begin(), image.end(), [](float v) { return !std::isfinite(v); });
    if (bad != image.end()) {
      throw std::invalid_argument("image_metrics: " + std::string(name) + " pixel " +
                                  std::to_string(bad - image.begin()) + " is " + std::to_string(*bad) +
                                  ", not a finite value");
    }
  }
  double ae = 0;
  for (std::size_t i = 0; i < n; ++i) ae += std::abs(static_cast<double>(render[i]) - target[i]);
  ViewMetrics m;
  m.psnr = gmf::psnr(render, target);
  m.mae = ae / static_cast<double>(n);
  LossWorkspace workspace;
  m.ssim = 1.0 - ssim_loss(render, target, width, height, 0.0, std::span<float>(), workspace);
  return m;
}

ForegroundSplit foreground_split(std::span<const float> render, std::span<const float> target, double level) {
  if (render.size() != target.size()) {
    throw std::invalid_argument("foreground_split: images of " + std::to_string(render.size()) + " and " +
                                std::to_string(target.size()) + " pixels");
  }
  double se_fg = 0, se_bg = 0;
  ForegroundSplit s;
  for (std::size_t i = 0; i < render.size(); ++i) {
    const double d = static_cast<double>(render[i]) - target[i];
    if (target[i] >= level) {
      se_fg += d * d;
      ++s.foreground;
    } else {
      se_bg += d * d;
    }
  }
  const std::size_t background = render.size() - s.foreground;
  auto psnr_of = [](double se, std::size_t n) {
    if (n == 0) return 0.0;
    return se > 0 ? gmf::psnr_from_mse(se / static_cast<double>(n)) : std::numeric_limits<double>::infinity();
  };
  s.psnr_fg = psnr_of(se_fg, s.foreground);
  s.psnr_bg = psnr_of(se_bg, background);
  s.background_error_share = se_fg + se_bg > 0 ? se_bg / (se_fg + se_bg) : 0.0;
  return s;
}

MetricSummary summarize(std::span<const double> values) {
  MetricSummary s;
  if (values.empty()) return s;
  double sum = 0;
  s.min = s.max = values[0];
  for (double v : values) {
    sum += v;
    s.min = std::min(s.min, v);
    s.max = std::max(s.max, v);
  }
  s.mean = sum / static_cast<double>(values.size());
  double var = 0;
  for (double v : values) var += (v - s.mean) * (v - s.mean);
  s.std = std::sqrt(var / static_cast<double>(values.size()));
  return s;
}

io::Image8 comparison_image(std::span<const float> target, std::span<const float> render, int width, int height,
                            float error_max) {
  io::Image8 img;
  img.width = 3 * width;
  img.height = height;
  img.channels = 3;
  img.pixels.assign(static_cast<std::size_t>(img.width) * height * 3, 0);
  auto grey = [](float v) { return static_cast<std::uint8_t>(std::lround(255.0f * std::clamp(v, 0.0f, 1.0f))); };
  for (int r = 0; r < height; ++r) {
    for (int c = 0; c < width; ++c) {
      const std::size_t i = static_cast<std::size_t>(r) * width + c;
      std::uint8_t* row = img.pixels.data() + static_cast<std::size_t>(r) * img.width * 3;
      const std::uint8_t t = grey(target[i]), p = grey(render[i]);
      for (int ch = 0; ch < 3; ++ch) {
        row[3 * c + ch] = t;
        row[3 * (width + c) + ch] = p;
      }
      // black -> red -> yellow -> white over [0, error_max]
      const float e = std::clamp(std::abs(render[i] - target[i]) / error_max, 0.0f, 1.0f) * 3.0f;
      std::uint8_t* out = row + 3 * (2 * width + c);
      out[0] = grey(std::min(e, 1.0f));
      out[1] = grey(std::clamp(e - 1.0f, 0.0f, 1.0f));
      out[2] = grey(std::clamp(e - 2.0f, 0.0f, 1.0f));
    }
  }
  return img;
}

}  // namespace hisnegs::splat
