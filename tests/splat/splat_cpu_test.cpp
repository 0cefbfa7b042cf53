// SPDX-License-Identifier: Apache-2.0
// What only the TBB splatting back end has: its ellipse-band binning and its opt-in
// skip counter. Forward and backward against the reference: splat_backend_test.cpp.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <utility>
#include <vector>

#include "splat/detail/splat_cpu_tiles.hpp"
#include "splat/splat_math.hpp"
#include "splat/splat_renderer.hpp"
#include "tests/splat/splat_test_scenes.hpp"

namespace hisnegs::splat {
namespace {

using testing::render;

// Binning: every pixel centre inside the δ ellipse lies in the columns reported
// for its band of 16 rows (no term is ever lost), on random ellipses of every
// size, elongation and angle, including ones partly off the image; both the
// scalar rule and the back end's SIMD tile_bands.
TEST(SplatCpu, EllipseBandsHoldEveryPixelInsideTheCutoff) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> u01(0, 1);
  constexpr int kTile = 16, kRows = 96;
  const double delta = 16.0;
  long band_columns = 0, box_columns = 0;
  for (int trial = 0; trial < 400; ++trial) {
    const double s1 = 0.3 + 12 * u01(rng), s2 = 0.3 + 12 * u01(rng), angle = 3.2 * u01(rng);
    const double c = std::cos(angle), sn = std::sin(angle);
    const double sxx = c * c * s1 * s1 + sn * sn * s2 * s2, syy = sn * sn * s1 * s1 + c * c * s2 * s2;
    const double sxy = c * sn * (s1 * s1 - s2 * s2), det = sxx * syy - sxy * sxy;
    Splat2D<double> g{};
    g.u = -20 + 140 * u01(rng);
    g.v = -20 + 136 * u01(rng);
    g.con_a = syy / det;
    g.con_b = -sxy / det;
    g.con_c = sxx / det;
    const EllipseRows<double> e = ellipse_rows(g, delta, 1.0);
    std::vector<std::pair<int, int>> cols(kRows / kTile, {1, 0});
    for_each_ellipse_band(e, 0, kRows / kTile - 1, kTile, 1e-6, [&](int ty, int c0, int c1) { cols[ty] = {c0, c1}; });
    // The SIMD version the CPU back end bins with (float, δ widened as there),
    // for the image's 6 tile rows and 12 tile columns.
    Splat2D<float> gf{};
    gf.u = static_cast<float>(g.u);
    gf.v = static_cast<float>(g.v);
    gf.con_a = static_cast<float>(g.con_a);
    gf.con_b = static_cast<float>(g.con_b);
    gf.con_c = static_cast<float>(g.con_c);
    const EllipseRows<float> ef = ellipse_rows(gf, static_cast<float>(delta), 1.0f + 1e-3f);
    std::int16_t tx0[detail::kBandsAtOnce], tx1[detail::kBandsAtOnce];
    const detail::BandJob job{
        {ef.u, ef.v, ef.slope, ef.k1, ef.k2, ef.x_right, ef.dy_right, 0.25f}, 0, kRows / kTile, 0, 11, tx0, tx1};
    detail::tile_bands(&job, 1);
    const double half_w = std::sqrt(delta * sxx);
    for (int ty = 0; ty < kRows / kTile; ++ty) {
      for (int y = ty * kTile; y < (ty + 1) * kTile; ++y) {
        for (int x = 0; x < 200; ++x) {  // columns left of the image are clamped to −2
          if (splat_distance(g, x + 0.5, y + 0.5) > delta) continue;
          EXPECT_TRUE(x >= cols[ty].first && x <= cols[ty].second)
              << "trial " << trial << " pixel (" << x << ", " << y << ") outside band " << ty << " columns ["
              << cols[ty].first << ", " << cols[ty].second << "]";
          if (x < 12 * kTile) {
            EXPECT_TRUE(x / kTile >= tx0[ty] && x / kTile <= tx1[ty])
                << "trial " << trial << " pixel (" << x << ", " << y << ") outside tile_bands row " << ty << " ["
                << tx0[ty] << ", " << tx1[ty] << "]";
          }
        }
      }
      if (cols[ty].first <= cols[ty].second) {
        band_columns += cols[ty].second - cols[ty].first + 1;
        box_columns += static_cast<long>(2 * half_w) + 1;
      }
    }
  }
  // Tighter than the bounding box on average (rotated, elongated ellipses).
  EXPECT_LT(band_columns, 0.8 * box_columns);
}

// The CPU counts skipped terms only when asked (SplatSettings::count_skipped: counting
// costs ~1.5x the soft-MIP time) and otherwise reports 0 although it skips (CUDA
// counts always). That both images stay within the skip rule's bound is checked for
// every back end in SplatBackend.SkippedTermsAreCountedAndNegligible.
TEST(SplatCpu, SkippedTermsAreCountedOnlyWhenAsked) {
  auto renderer = make_splat_renderer(Backend::kCpu);
  const auto scene = testing::bright_over_dim_scene(24);
  SplatSettings skip;
  skip.skip_log_weight = 8.0f;
  skip.beta = 50.0f;
  skip.count_skipped = true;
  render(*renderer, scene, skip);
  EXPECT_GT(renderer->stats().skipped_terms, 0);  // this scene does skip
  skip.count_skipped = false;
  render(*renderer, scene, skip);
  EXPECT_EQ(renderer->stats().skipped_terms, 0);
}

}  // namespace
}  // namespace hisnegs::splat

namespace hisnegs::splat {
namespace {

// At the largest β the options allow, the soft MIP is still exact in float: no
// pixel below 0 or above the hard MIP, and within the softmax's own bound
// (n − 1)/(e β) of it (at 1e9, before the bound, pixels went to −0.27).
TEST(SplatCpu, SoftMipAtTheLargestBetaStaysBetweenZeroAndTheHardMip) {
  const testing::SplatScene scene = testing::make_splat_scene(60, 17, 48, 40);
  auto renderer = make_splat_renderer(Backend::kCpu);
  SplatSettings soft;
  soft.mode = MipMode::kSoftmax;
  soft.beta = static_cast<float>(kMaxSoftMipBeta);
  SplatSettings hard = soft;
  hard.mode = MipMode::kMax;
  const std::vector<float> s = testing::render(*renderer, scene, soft);
  const std::vector<float> h = testing::render(*renderer, scene, hard);
  const double bound = 59.0 / (std::exp(1.0) * kMaxSoftMipBeta) + 1e-5;
  for (std::size_t i = 0; i < s.size(); ++i) {
    ASSERT_GE(s[i], 0.0f) << "pixel " << i;
    ASSERT_LE(s[i], h[i] + 1e-5f) << "pixel " << i;
    ASSERT_NEAR(s[i], h[i], bound) << "pixel " << i;
  }
  EXPECT_GT(*std::max_element(h.begin(), h.end()), 0.3f);  // the scene is in view
}

}  // namespace
}  // namespace hisnegs::splat
