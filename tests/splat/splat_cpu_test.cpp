// The TBB splatting back end against the double reference: forward (soft at two
// β, hard) and backward, on random scenes, plus the skip rule's counted effect.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <utility>
#include <vector>

#include "splat/detail/splat_cpu_tiles.hpp"
#include "splat/splat_math.hpp"
#include "splat/splat_reference.hpp"
#include "splat/splat_renderer.hpp"
#include "tests/splat/splat_test_scenes.hpp"

namespace hisnegs::splat {
namespace {

using testing::make_splat_scene;
using testing::max_abs_diff;
using testing::render;
using testing::to_float;

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
    const detail::BandJob job{{ef.u, ef.v, ef.slope, ef.k1, ef.k2, ef.x_right, ef.dy_right, 0.25f}, 0, kRows / kTile, 0,
                              11, tx0, tx1};
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

// Float math against double: values are in [0, 1] and each pixel is a softmax-weighted
// mean of at most a few dozen terms, so 1e-4 absolute leaves ~50x headroom over float
// rounding. The cutoff is huge here so that no pixel sits on the δ boundary, where
// float and double may decide q <= δ differently (an a e^-8 jump).
TEST(SplatCpu, ForwardMatchesReference) {
  auto renderer = make_splat_renderer(Backend::kCpu);
  for (std::uint64_t seed : {21u, 22u}) {
    const auto scene = make_splat_scene(30, seed, 70, 45);  // several tiles, a partial tile column and row
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    for (MipMode mode : {MipMode::kSoft, MipMode::kHard}) {
      for (float beta : {8.0f, 50.0f}) {
        SplatSettings s;
        s.mode = mode;
        s.beta = beta;
        s.cutoff = 1e6f;
        s.skip_log_weight = 0.0f;
        const std::vector<double> ref = render_reference(scene.params, view, s);
        const std::vector<float> img = render(*renderer, scene, s);
        EXPECT_LT(max_abs_diff(img, ref), 1e-4) << "seed " << seed << " beta " << beta << " hard " << (mode == MipMode::kHard);
      }
    }
  }
}

// With the default δ = 16 only pixels where a term sits on the δ boundary may differ
// by more than rounding (testing::boundary_flip_bound), and they are rare.
TEST(SplatCpu, ForwardMatchesReferenceAtDefaultCutoff) {
  auto renderer = make_splat_renderer(Backend::kCpu);
  const auto scene = make_splat_scene(40, 23, 64, 48);
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  SplatSettings s;
  s.skip_log_weight = 0.0f;
  const std::vector<double> ref = render_reference(scene.params, view, s);
  const std::vector<float> img = render(*renderer, scene, s);
  EXPECT_LT(max_abs_diff(img, ref), testing::boundary_flip_bound(s) + 1e-4);
  int close = 0;
  for (std::size_t i = 0; i < img.size(); ++i) close += std::abs(img[i] - ref[i]) < 1e-4 ? 1 : 0;
  EXPECT_GT(close, static_cast<int>(0.99 * img.size()));
  EXPECT_GT(renderer->stats().visible, 0);
  EXPECT_GE(renderer->stats().tile_entries, renderer->stats().visible);
}

// Gaussians taller than 8 tiles (binned by the scalar band rule instead of the
// stored SIMD bands) on an image of 12 x 10 tiles, soft and hard, with the skip
// rule on: every tile they reach is rendered as the reference renders it.
TEST(SplatCpu, LargeGaussiansOverManyTilesMatchReference) {
  auto renderer = make_splat_renderer(Backend::kCpu);
  const auto scene = make_splat_scene(12, 31, 190, 160, 0.15, 0.35);
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  for (MipMode mode : {MipMode::kSoft, MipMode::kHard}) {
    SplatSettings s;
    s.mode = mode;
    const std::vector<double> ref = render_reference(scene.params, view, s);
    const std::vector<float> img = render(*renderer, scene, s);
    // Skipped terms move a pixel by at most (terms) e^-20; boundary pixels as above.
    EXPECT_LT(max_abs_diff(img, ref), testing::boundary_flip_bound(s) + 1e-4);
    int close = 0;
    for (std::size_t i = 0; i < img.size(); ++i) close += std::abs(img[i] - ref[i]) < 1e-4 ? 1 : 0;
    EXPECT_GT(close, static_cast<int>(0.99 * img.size())) << "hard " << (mode == MipMode::kHard);
    // Some Gaussian spans more than 8 tile rows (8 * 16 = 128 pixels).
    double tallest = 0;
    for (std::size_t k = 0; k < scene.params.size() / gmf::kGaussianParamCount; ++k) {
      const Splat2D<double> g =
          project_gaussian(&scene.params[gmf::kGaussianParamCount * k], view, double(s.cutoff), 0.0);
      if (g.visible) tallest = std::max(tallest, 2 * g.half_h);
    }
    EXPECT_GT(tallest, 9 * 16.0);
  }
}

// The skip rule drops only terms whose weight is below e^-skip of the pixel's max,
// so the image moves by less than (terms skipped) e^-skip; the count is reported.
TEST(SplatCpu, SkippedTermsAreCountedAndNegligible) {
  auto renderer = make_splat_renderer(Backend::kCpu);
  auto scene = make_splat_scene(60, 24, 64, 48, 0.08, 0.2);
  // A few bright Gaussians over many dim ones so that skipping happens.
  for (int k = 0; k < 60; ++k) scene.params[11 * k + 10] = k < 6 ? 3.0 : -2.5;
  SplatSettings exact;
  exact.skip_log_weight = 0.0f;
  exact.beta = 50.0f;
  exact.count_skipped = true;
  const std::vector<float> a = render(*renderer, scene, exact);
  EXPECT_EQ(renderer->stats().skipped_terms, 0);
  SplatSettings skip = exact;
  skip.skip_log_weight = 8.0f;
  const std::vector<float> b = render(*renderer, scene, skip);
  const std::int64_t skipped = renderer->stats().skipped_terms;
  EXPECT_GT(skipped, 0);
  double diff = 0;
  for (std::size_t i = 0; i < a.size(); ++i) diff = std::max(diff, double(std::abs(a[i] - b[i])));
  EXPECT_LT(diff, 60 * std::exp(-8.0) + 1e-6);
  // Without counting (the default, and its faster culling) the image is the same
  // up to the same bound, and the count stays 0.
  skip.count_skipped = false;
  const std::vector<float> c = render(*renderer, scene, skip);
  EXPECT_EQ(renderer->stats().skipped_terms, 0);
  double diff_uncounted = 0;
  for (std::size_t i = 0; i < a.size(); ++i) diff_uncounted = std::max(diff_uncounted, double(std::abs(a[i] - c[i])));
  EXPECT_LT(diff_uncounted, 60 * std::exp(-8.0) + 1e-6);
}

// Backward against the reference: both chain the same per-pixel terms; in float the
// per-Gaussian sums carry ~1e-6 relative rounding, so each gradient is compared
// relative to the largest gradient of its parameter kind (1e-3).
TEST(SplatCpu, BackwardMatchesReference) {
  auto renderer = make_splat_renderer(Backend::kCpu);
  for (std::uint64_t seed : {31u, 32u}) {
    const auto scene = make_splat_scene(25, seed, 60, 40);
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    SplatSettings s;
    s.cutoff = 1e6f;
    s.skip_log_weight = 0.0f;
    s.beta = seed == 31 ? 50.0f : 10.0f;
    std::mt19937_64 rng(seed);
    std::uniform_real_distribution<double> u(-1, 1);
    std::vector<double> w(static_cast<std::size_t>(scene.K.width) * scene.K.height);
    for (double& x : w) x = u(rng);
    std::vector<double> screen_ref;
    const std::vector<double> ref = render_reference_backward(scene.params, view, s, w, &screen_ref);
    render(*renderer, scene, s);
    std::vector<float> grad(scene.params.size(), 0.0f), screen(scene.params.size() / 11, 0.0f);
    renderer->backward(to_float(w), grad, screen);
    double largest[11] = {};
    for (std::size_t i = 0; i < ref.size(); ++i) largest[i % 11] = std::max(largest[i % 11], std::abs(ref[i]));
    for (std::size_t i = 0; i < ref.size(); ++i) {
      EXPECT_LT(std::abs(grad[i] - ref[i]), 1e-3 * largest[i % 11] + 1e-9) << "seed " << seed << " param " << i;
    }
    for (std::size_t k = 0; k < screen.size(); ++k) EXPECT_NEAR(screen[k], screen_ref[k], 1e-3 * screen_ref[k] + 1e-6);
  }
}

// backward() adds: two calls give twice the gradient (mini-batches of views rely on it).
// The backward with the skip rule on (the default): it differentiates exactly the
// terms the forward summed, culled by the same row floors and whole-tile test, and
// the terms it drops weigh below e^-20, so it matches the exact reference. A few
// bright Gaussians over dim ones make the rule drop terms (checked by the count).
TEST(SplatCpu, BackwardWithSkippingMatchesReference) {
  auto renderer = make_splat_renderer(Backend::kCpu);
  auto scene = make_splat_scene(40, 41, 64, 48, 0.3, 0.5);  // wide: every row has bright pixels only
  for (int k = 0; k < 40; ++k) scene.params[11 * k + 10] = k % 8 == 0 ? 3.0 : -2.5;
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  SplatSettings s;
  s.cutoff = 1e6f;  // no δ boundary (see ForwardMatchesReference)
  s.beta = 50.0f;
  ASSERT_GT(s.skip_log_weight, 0.0f);
  std::mt19937_64 rng(41);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<double> w(static_cast<std::size_t>(scene.K.width) * scene.K.height);
  for (double& x : w) x = u(rng);
  SplatSettings exact = s;
  exact.skip_log_weight = 0.0f;
  const std::vector<double> ref = render_reference_backward(scene.params, view, exact, w, nullptr);
  SplatSettings counted = s;
  counted.count_skipped = true;
  render(*renderer, scene, counted);
  EXPECT_GT(renderer->stats().skipped_terms, 1000);
  render(*renderer, scene, s);
  std::vector<float> grad(scene.params.size(), 0.0f);
  renderer->backward(to_float(w), grad, {});
  double largest[11] = {};
  for (std::size_t i = 0; i < ref.size(); ++i) largest[i % 11] = std::max(largest[i % 11], std::abs(ref[i]));
  for (std::size_t i = 0; i < ref.size(); ++i) {
    EXPECT_LT(std::abs(grad[i] - ref[i]), 1e-3 * largest[i % 11] + 1e-9) << "param " << i;
  }
}

TEST(SplatCpu, BackwardAccumulates) {
  auto renderer = make_splat_renderer(Backend::kCpu);
  const auto scene = make_splat_scene(10, 41, 48, 32);
  SplatSettings s;
  render(*renderer, scene, s);
  const std::vector<float> ones(static_cast<std::size_t>(48 * 32), 1.0f);
  std::vector<float> once(scene.params.size(), 0.0f);
  renderer->backward(ones, once);
  std::vector<float> twice(scene.params.size(), 0.0f);
  renderer->backward(ones, twice);
  renderer->backward(ones, twice);
  double largest = 0;
  for (float g : once) largest = std::max(largest, double(std::abs(g)));
  ASSERT_GT(largest, 0.0);
  for (std::size_t i = 0; i < once.size(); ++i) EXPECT_NEAR(twice[i], 2 * once[i], 1e-5 * largest);
}

TEST(SplatCpu, BadSpansAreRejected) {
  auto renderer = make_splat_renderer(Backend::kCpu);
  const auto scene = make_splat_scene(3, 42, 16, 16);
  std::vector<float> p = to_float(scene.params);
  std::vector<float> img(10);
  EXPECT_THROW(renderer->forward(p, scene.K, scene.view, SplatSettings{}, img), std::invalid_argument);
  p.pop_back();
  img.resize(256);
  EXPECT_THROW(renderer->forward(p, scene.K, scene.view, SplatSettings{}, img), std::invalid_argument);
}

}  // namespace
}  // namespace hisnegs::splat
