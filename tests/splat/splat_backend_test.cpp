// SPDX-License-Identifier: Apache-2.0
// Every splatting back end (TBB, CUDA) through the public SplatRenderer interface
// against the double reference: forward, backward, skipping, culling, errors, state
// between frames. Checks of one back end's internals stay in splat_{cpu,cuda}_test.cpp.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "splat/backend.hpp"
#include "splat/render_views.hpp"
#include "splat/splat_reference.hpp"
#include "splat/splat_renderer.hpp"
#include "tests/splat/splat_test_scenes.hpp"

namespace hisnegs::splat {
namespace {

using testing::boundary_flip_bound;
using testing::count_far;
using testing::largest_per_kind;
using testing::make_splat_scene;
using testing::max_abs_diff;
using testing::random_weights;
using testing::render;
using testing::to_float;

// One instance per back end; a back end this build or machine lacks skips with the
// reason (not built, or no usable device) instead of failing. A new back end gets
// every check here by adding it to the INSTANTIATE_TEST_SUITE_P list below.
class SplatBackend : public ::testing::TestWithParam<Backend> {
 protected:
  void SetUp() override {
    const std::string why = testing::why_backend_untestable(GetParam());
    if (!why.empty()) GTEST_SKIP() << why;
    renderer_ = make_splat_renderer(GetParam());
    ASSERT_EQ(renderer_->backend(), GetParam());
  }
  // Another renderer of the same back end (a fresh one, with no state of its own).
  [[nodiscard]] std::unique_ptr<SplatRenderer> fresh_renderer() const { return make_splat_renderer(GetParam()); }

  std::unique_ptr<SplatRenderer> renderer_;
};

// The small random scenes the forward and backward comparisons run on: the CPU's
// and the CUDA's former scenes, now rendered by every back end.
struct SceneCase {
  std::uint64_t seed;
  int count, width, height;
};
// Several 16 x 16 tiles; 70 x 45 leaves a partial tile column and row, 64 x 48 none.
constexpr SceneCase kForwardScenes[] = {{21, 30, 70, 45}, {22, 30, 70, 45}, {51, 20, 64, 48},
                                        {52, 20, 64, 48}, {53, 20, 70, 45}, {54, 20, 70, 45}};

std::string describe(const SceneCase& c) {
  return "seed " + std::to_string(c.seed) + " (" + std::to_string(c.count) + " Gaussians, " + std::to_string(c.width) +
         " x " + std::to_string(c.height) + ")";
}

// Float math against double: values lie in [0, 1] and each pixel is a softmax-weighted
// mean of at most a few dozen terms whose float rounding (projection, q, exp, the
// online sums) is ~1e-6, so 1e-4 absolute leaves ~50x headroom over float rounding
// (the CPU and CUDA back ends used the same bound). The cutoff is huge so that no
// pixel sits on the δ boundary, where float and double may decide q <= δ differently
// (a jump of up to a e^-8); skipping is off so the sums are complete. With that δ
// every Gaussian's ellipse meets the image, so all are visible.
TEST_P(SplatBackend, SoftForwardMatchesReference) {
  for (const SceneCase& c : kForwardScenes) {
    const auto scene = make_splat_scene(c.count, c.seed, c.width, c.height);
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    for (float beta : {8.0f, 50.0f}) {
      SplatSettings s;
      s.beta = beta;
      s.cutoff = 1e6f;
      s.skip_log_weight = 0.0f;
      const std::vector<double> ref = render_reference(scene.params, view, s);
      const std::vector<float> img = render(*renderer_, scene, s);
      EXPECT_LT(max_abs_diff(img, ref), 1e-4) << describe(c) << " beta " << beta;
      EXPECT_EQ(renderer_->stats().visible, c.count) << describe(c) << " beta " << beta;
    }
  }
}

// Hard MIP is a max of float-evaluated terms: ~1e-6 from the double max (1e-4 as
// above). β and the skip rule belong to soft MIP: hard mode must ignore both, so each
// scene is rendered at two β and with skipping off and at its default.
TEST_P(SplatBackend, HardForwardMatchesReference) {
  for (const SceneCase& c : kForwardScenes) {
    const auto scene = make_splat_scene(c.count, c.seed, c.width, c.height);
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    for (float beta : {8.0f, 50.0f}) {
      for (float skip : {0.0f, SplatSettings{}.skip_log_weight}) {
        SplatSettings s;
        s.mode = MipMode::kMax;
        s.beta = beta;
        s.cutoff = 1e6f;
        s.skip_log_weight = skip;
        const std::vector<double> ref = render_reference(scene.params, view, s);
        const std::vector<float> img = render(*renderer_, scene, s);
        EXPECT_LT(max_abs_diff(img, ref), 1e-4) << describe(c) << " beta " << beta << " skip " << skip;
        EXPECT_EQ(renderer_->stats().visible, c.count) << describe(c) << " beta " << beta << " skip " << skip;
      }
    }
  }
}

// With the default δ = 16 the tile rectangles matter (a Gaussian cut short by a wrong
// rectangle would be off by O(a)). Only pixels where a term sits on the δ boundary may
// differ by more than rounding, by at most boundary_flip_bound, and such pixels are
// rare (a float q lands within its rounding of δ on ~1e-6 of the boundary pairs):
// fewer than 1% of the pixels beyond 1e-4. (The CPU asked for more than 99% within
// 1e-4, i.e. far < n − ⌊0.99 n⌋, CUDA for far <= ⌊0.01 n⌋; far < 0.01 n is at least
// as strict as both for every n.)
TEST_P(SplatBackend, ForwardMatchesReferenceAtDefaultCutoff) {
  for (std::uint64_t seed : {23u, 55u}) {
    const auto scene = make_splat_scene(40, seed, 64, 48);
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    for (MipMode mode : {MipMode::kSoftmax, MipMode::kMax}) {
      SplatSettings s;
      s.mode = mode;
      s.skip_log_weight = 0.0f;
      const std::string what = "seed " + std::to_string(seed) + " hard " + std::to_string(mode == MipMode::kMax);
      const std::vector<double> ref = render_reference(scene.params, view, s);
      const std::vector<float> img = render(*renderer_, scene, s);
      EXPECT_LT(max_abs_diff(img, ref), boundary_flip_bound(s) + 1e-4) << what;
      EXPECT_LT(count_far(img, ref, 1e-4), 0.01 * double(img.size())) << what;
      EXPECT_GT(renderer_->stats().visible, 0) << what;
      EXPECT_GE(renderer_->stats().tile_entries, renderer_->stats().visible) << what;
    }
  }
}

// Gaussians taller than 8 tiles on an image of 12 x 10 tiles, soft and hard, with the
// skip rule on: every tile they reach is rendered as the reference renders it. (On the
// CPU such Gaussians are binned by the scalar band rule instead of the stored SIMD
// bands; on CUDA they make long per-Gaussian tile lists.) Skipped terms move a pixel
// by at most (terms) e^-20; boundary pixels as in ForwardMatchesReferenceAtDefaultCutoff
// (here n = 30400: at most 303 far pixels, as the CPU test allowed).
TEST_P(SplatBackend, LargeGaussiansOverManyTilesMatchReference) {
  const auto scene = make_splat_scene(12, 31, 190, 160, 0.15, 0.35);
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  for (MipMode mode : {MipMode::kSoftmax, MipMode::kMax}) {
    SplatSettings s;
    s.mode = mode;
    const std::string what = "hard " + std::to_string(mode == MipMode::kMax);
    const std::vector<double> ref = render_reference(scene.params, view, s);
    const std::vector<float> img = render(*renderer_, scene, s);
    EXPECT_LT(max_abs_diff(img, ref), boundary_flip_bound(s) + 1e-4) << what;
    EXPECT_LT(count_far(img, ref, 1e-4), 0.01 * double(img.size())) << what;
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

// The skip rule drops only terms whose weight is below e^-skip of the pixel's running
// max, so the image moves by less than (Gaussians: 60) e^-skip; with count_skipped the
// dropped terms are counted (both back ends count only then). Without counting
// (the default, with its earlier stop) the image obeys the same bound.
TEST_P(SplatBackend, SkippedTermsAreCountedAndNegligible) {
  for (std::uint64_t seed : {24u, 76u}) {
    const auto scene = testing::bright_over_dim_scene(seed);
    SplatSettings exact;
    exact.skip_log_weight = 0.0f;
    exact.beta = 50.0f;
    exact.count_skipped = true;
    const std::vector<float> a = render(*renderer_, scene, exact);
    EXPECT_EQ(renderer_->stats().skipped_terms, 0) << "seed " << seed;
    SplatSettings skip = exact;
    skip.skip_log_weight = 8.0f;
    const std::vector<float> b = render(*renderer_, scene, skip);
    EXPECT_GT(renderer_->stats().skipped_terms, 0) << "seed " << seed;
    EXPECT_LT(max_abs_diff(a, b), 60 * std::exp(-8.0) + 1e-6) << "seed " << seed;
    skip.count_skipped = false;
    const std::vector<float> c = render(*renderer_, scene, skip);
    EXPECT_LT(max_abs_diff(a, c), 60 * std::exp(-8.0) + 1e-6) << "seed " << seed << " uncounted";
  }
}

// Backward against the reference: both chain the same per-pixel terms through the
// same splat_math.hpp functions. The float sums (per tile, then over tiles: in double
// on the CPU, float atomicAdd on CUDA) carry ~1e-6 relative rounding, so each gradient
// is compared relative to the largest gradient of its parameter kind: 1e-3 (both back
// ends used it). The cutoff is huge for the reason in SoftForwardMatchesReference (a
// boundary term would also move the gradient).
TEST_P(SplatBackend, BackwardMatchesReference) {
  struct BackwardCase {
    SceneCase scene;
    float beta;
  };
  const BackwardCase cases[] = {
      {{31, 25, 60, 40}, 50.0f}, {{32, 25, 60, 40}, 10.0f}, {{61, 20, 64, 48}, 50.0f}, {{62, 20, 64, 48}, 8.0f}};
  for (const BackwardCase& c : cases) {
    const auto scene = make_splat_scene(c.scene.count, c.scene.seed, c.scene.width, c.scene.height);
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    SplatSettings s;
    s.cutoff = 1e6f;
    s.skip_log_weight = 0.0f;
    s.beta = c.beta;
    const std::vector<double> w =
        random_weights(static_cast<std::size_t>(scene.K.width) * scene.K.height, c.scene.seed);
    std::vector<double> screen_ref;
    const std::vector<double> ref = render_reference_backward(scene.params, view, s, w, &screen_ref);
    render(*renderer_, scene, s);
    std::vector<float> grad(scene.params.size(), 0.0f), screen(scene.params.size() / 11, 0.0f);
    renderer_->backward(to_float(w), grad, screen);
    const std::vector<double> largest = largest_per_kind(ref);
    for (std::size_t i = 0; i < ref.size(); ++i) {
      EXPECT_LT(std::abs(grad[i] - ref[i]), 1e-3 * largest[i % 11] + 1e-9)
          << describe(c.scene) << " param " << i << " (kind " << i % 11 << "): " << grad[i] << " ref " << ref[i];
    }
    for (std::size_t k = 0; k < screen.size(); ++k) {
      EXPECT_NEAR(screen[k], screen_ref[k], 1e-3 * screen_ref[k] + 1e-6) << describe(c.scene) << " Gaussian " << k;
    }
  }
}

// A floor per pixel (the background's MIP): forward in both modes and the soft
// backward match the reference with the same floor (tolerances as above), with the
// skip rule on (the floor raises m, so more terms are skipped), on pixels no
// Gaussian reaches too.
TEST_P(SplatBackend, FloorIsOneMoreTermPerPixel) {
  const auto scene = make_splat_scene(30, 71, 70, 45);
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  std::vector<float> floor(static_cast<std::size_t>(scene.K.width) * scene.K.height);
  for (std::size_t i = 0; i < floor.size(); ++i) floor[i] = i % 7 == 0 ? 0.0f : 0.02f + 0.3f * ((i * 37) % 101) / 101.0f;
  for (const MipMode mode : {MipMode::kSoftmax, MipMode::kMax}) {
    SplatSettings s;
    s.mode = mode;
    s.beta = 30.0f;
    s.cutoff = 1e6f;
    s.skip_log_weight = 0.0f;
    s.floor = floor;
    const std::vector<double> ref = render_reference(scene.params, view, s);
    const std::vector<float> img = render(*renderer_, scene, s);
    EXPECT_LT(max_abs_diff(img, ref), 1e-4) << (mode == MipMode::kSoftmax ? "soft" : "hard");
  }
  SplatSettings s;
  s.beta = 30.0f;
  s.cutoff = 1e6f;
  s.floor = floor;
  const std::vector<double> w = random_weights(floor.size(), 72);
  const std::vector<double> ref = render_reference_backward(scene.params, view, s, w);
  render(*renderer_, scene, s);
  std::vector<float> grad(scene.params.size(), 0.0f);
  renderer_->backward(to_float(w), grad);
  const std::vector<double> largest = largest_per_kind(ref);
  for (std::size_t i = 0; i < ref.size(); ++i) {
    EXPECT_LT(std::abs(grad[i] - ref[i]), 1e-3 * largest[i % 11] + 1e-9) << "param " << i;
  }
  // A floor of the wrong size is refused.
  s.floor = std::span<const float>(floor.data(), floor.size() - 1);
  std::vector<float> image(floor.size());
  EXPECT_THROW(renderer_->forward(to_float(scene.params), scene.K, scene.view, s, image), std::invalid_argument);
}

// The backward with the skip rule on (the default): it differentiates exactly the
// terms the forward summed (on the CPU: culled by the same row floors and whole-tile
// test), and the terms it drops weigh
// below e^-20, so it matches the exact reference (1e-3 of each kind's largest, as in
// BackwardMatchesReference). A few bright Gaussians over dim ones make the rule drop
// terms (checked by the count, so count_skipped is set for that forward).
TEST_P(SplatBackend, BackwardWithSkippingMatchesReference) {
  auto scene = make_splat_scene(40, 41, 64, 48, 0.3, 0.5);  // wide: every row has bright pixels only
  for (int k = 0; k < 40; ++k) scene.params[11 * k + 10] = k % 8 == 0 ? 3.0 : -2.5;
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  SplatSettings s;
  s.cutoff = 1e6f;  // no δ boundary (see SoftForwardMatchesReference)
  s.beta = 50.0f;
  ASSERT_GT(s.skip_log_weight, 0.0f);
  const std::vector<double> w = random_weights(static_cast<std::size_t>(scene.K.width) * scene.K.height, 41);
  SplatSettings exact = s;
  exact.skip_log_weight = 0.0f;
  const std::vector<double> ref = render_reference_backward(scene.params, view, exact, w, nullptr);
  SplatSettings counted = s;
  counted.count_skipped = true;
  render(*renderer_, scene, counted);
  EXPECT_GT(renderer_->stats().skipped_terms, 1000);
  render(*renderer_, scene, s);
  std::vector<float> grad(scene.params.size(), 0.0f);
  renderer_->backward(to_float(w), grad, {});
  const std::vector<double> largest = largest_per_kind(ref);
  for (std::size_t i = 0; i < ref.size(); ++i) {
    EXPECT_LT(std::abs(grad[i] - ref[i]), 1e-3 * largest[i % 11] + 1e-9)
        << "param " << i << " (kind " << i % 11 << "): " << grad[i] << " ref " << ref[i];
  }
}

// backward() adds into the caller's arrays: two calls give twice one call (mini-batches
// of views rely on it). CUDA's float atomics may add in another order each call, hence
// 1e-5 of the largest gradient (the CPU, deterministic, used the same bound).
TEST_P(SplatBackend, BackwardAccumulates) {
  for (std::uint64_t seed : {41u, 63u}) {
    const auto scene = make_splat_scene(10, seed, 48, 32);
    render(*renderer_, scene, SplatSettings{});
    const std::vector<float> ones(static_cast<std::size_t>(48 * 32), 1.0f);
    std::vector<float> once(scene.params.size(), 0.0f);
    renderer_->backward(ones, once);
    std::vector<float> twice(scene.params.size(), 0.0f);
    renderer_->backward(ones, twice);
    renderer_->backward(ones, twice);
    double largest = 0;
    for (float g : once) largest = std::max(largest, double(std::abs(g)));
    ASSERT_GT(largest, 0.0) << "seed " << seed;
    for (std::size_t i = 0; i < once.size(); ++i) {
      EXPECT_NEAR(twice[i], 2 * once[i], 1e-5 * largest) << "seed " << seed << " param " << i;
    }
  }
}

// Spans that do not match the intrinsics, a parameter array that is not whole
// Gaussians, and backward spans that do not match the last forward are errors.
TEST_P(SplatBackend, BadSpansAreRejected) {
  const auto scene = make_splat_scene(3, 42, 16, 16);
  std::vector<float> p = to_float(scene.params);
  std::vector<float> img(10);
  EXPECT_THROW(renderer_->forward(p, scene.K, scene.view, SplatSettings{}, img), std::invalid_argument);
  p.pop_back();
  img.resize(256);
  EXPECT_THROW(renderer_->forward(p, scene.K, scene.view, SplatSettings{}, img), std::invalid_argument);

  render(*renderer_, scene, SplatSettings{});
  const std::vector<float> dL_dimage(256, 1.0f), short_dL_dimage(255, 1.0f);
  std::vector<float> grad(scene.params.size(), 0.0f), short_grad(scene.params.size() - 1, 0.0f);
  std::vector<float> short_screen(2, 0.0f);
  EXPECT_THROW(renderer_->backward(short_dL_dimage, grad), std::invalid_argument);
  EXPECT_THROW(renderer_->backward(dL_dimage, short_grad), std::invalid_argument);
  EXPECT_THROW(renderer_->backward(dL_dimage, grad, short_screen), std::invalid_argument);
}

// No Gaussians, or all behind the camera: a black image, nothing visible, and a
// backward that adds nothing.
TEST_P(SplatBackend, EmptyAndCulledScenesRenderBlack) {
  auto scene = make_splat_scene(5, 75, 40, 32);
  const Eigen::Vector3d C = -scene.view.R_cam_from_world.transpose() * scene.view.t_cam_from_world;
  const Eigen::Vector3d forward = scene.view.R_cam_from_world.row(2).transpose();
  for (int k = 0; k < 5; ++k) {
    for (int a = 0; a < 3; ++a) scene.params[11 * k + a] = C[a] - 0.5 * forward[a];
  }
  const std::vector<float> img = render(*renderer_, scene, SplatSettings{});
  EXPECT_EQ(*std::max_element(img.begin(), img.end()), 0.0f);
  EXPECT_EQ(renderer_->stats().visible, 0);
  EXPECT_EQ(renderer_->stats().tile_entries, 0);
  std::vector<float> grad(scene.params.size(), 0.0f);
  renderer_->backward(std::vector<float>(img.size(), 1.0f), grad);
  EXPECT_EQ(*std::max_element(grad.begin(), grad.end()), 0.0f);
  EXPECT_EQ(*std::min_element(grad.begin(), grad.end()), 0.0f);

  std::vector<float> none_img(img.size(), 1.0f);
  renderer_->forward(std::span<const float>(), scene.K, scene.view, SplatSettings{}, none_img);
  EXPECT_EQ(*std::max_element(none_img.begin(), none_img.end()), 0.0f);
}

// A hard forward that did not keep its argmax (a render that only looks) has no backward.
TEST_P(SplatBackend, BackwardNeedsASoftForwardOrAKeptArgmax) {
  const auto scene = make_splat_scene(3, 77, 16, 16);
  SplatSettings hard;
  hard.mode = MipMode::kMax;
  const std::vector<float> img = render(*renderer_, scene, hard);
  std::vector<float> grad(scene.params.size(), 0.0f);
  EXPECT_THROW(renderer_->backward(img, grad), std::logic_error);
  hard.keep_argmax = true;
  (void)render(*renderer_, scene, hard);
  EXPECT_NO_THROW(renderer_->backward(img, grad));
}

// The hard MIP's backward (each pixel's gradient to its argmax Gaussian alone) matches
// the reference's, with and without a floor (a term that takes no gradient), at the
// default cutoff: the forward's image and the argmax it kept are the reference's.
TEST_P(SplatBackend, HardBackwardMatchesReference) {
  for (const SceneCase& c : {SceneCase{31, 25, 60, 40}, SceneCase{61, 20, 64, 48}, SceneCase{62, 40, 70, 45}}) {
    for (const bool with_floor : {false, true}) {
      const auto scene = make_splat_scene(c.count, c.seed, c.width, c.height);
      const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
      const std::size_t pixels = static_cast<std::size_t>(scene.K.width) * scene.K.height;
      SplatSettings s;
      s.mode = MipMode::kMax;
      s.keep_argmax = true;
      std::vector<float> floor;
      if (with_floor) {  // a floor under some pixels' max, over others'
        floor.assign(pixels, 0.0f);
        for (std::size_t i = 0; i < pixels; ++i) floor[i] = i % 3 == 0 ? 0.0f : 0.15f * static_cast<float>(i % 5);
        s.floor = floor;
      }
      const std::vector<double> w = random_weights(pixels, c.seed);
      std::vector<double> screen_ref;
      const std::vector<double> ref = render_reference_backward(scene.params, view, s, w, &screen_ref);
      const std::vector<float> img = render(*renderer_, scene, s);
      const std::vector<double> ref_img = render_reference(scene.params, view, s);
      EXPECT_LT(max_abs_diff(img, ref_img), 1e-4) << describe(c);
      std::vector<float> grad(scene.params.size(), 0.0f), screen(scene.params.size() / 11, 0.0f);
      renderer_->backward(to_float(w), grad, screen);
      const std::vector<double> largest = largest_per_kind(ref);
      ASSERT_GT(largest[gmf::kLogit], 0.0) << describe(c) << ": no Gaussian won a pixel";
      for (std::size_t i = 0; i < ref.size(); ++i) {
        EXPECT_LT(std::abs(grad[i] - ref[i]), 1e-3 * largest[i % 11] + 1e-9)
            << describe(c) << (with_floor ? " with a floor" : "") << " param " << i << " (kind " << i % 11
            << "): " << grad[i] << " ref " << ref[i];
      }
      for (std::size_t k = 0; k < screen.size(); ++k) {
        EXPECT_NEAR(screen[k], screen_ref[k], 1e-3 * screen_ref[k] + 1e-6) << describe(c) << " Gaussian " << k;
      }
    }
  }
}

// Two Gaussians over one pixel: the hard MIP's gradient reaches the brighter alone,
// as max-pooling's does; the soft MIP's reaches both.
TEST_P(SplatBackend, HardGradientReachesOnlyTheArgmax) {
  auto scene = make_splat_scene(2, 5, 32, 32);
  // Both centred on the middle of the view, the second dimmer and wider.
  for (int a = 0; a < 3; ++a) scene.params[11 + a] = scene.params[a];
  scene.params[10] = 2.0;                    // a = 0.88
  scene.params[11 + 10] = 0.0;               // a = 0.5
  for (int a = 3; a < 6; ++a) scene.params[11 + a] = scene.params[a] + 0.7;  // scales ×2
  const std::size_t pixels = 32 * 32;
  std::vector<float> img(pixels);
  SplatSettings probe;
  probe.mode = MipMode::kMax;
  img = render(*renderer_, scene, probe);
  const auto centre = static_cast<std::size_t>(std::max_element(img.begin(), img.end()) - img.begin());
  std::vector<float> w(pixels, 0.0f);
  w[centre] = 1.0f;  // dL/dI at the brightest pixel only, where the first Gaussian is the max
  for (const MipMode mode : {MipMode::kMax, MipMode::kSoftmax}) {
    SplatSettings s;
    s.mode = mode;
    s.keep_argmax = true;
    s.beta = 5.0f;
    (void)render(*renderer_, scene, s);
    std::vector<float> grad(scene.params.size(), 0.0f);
    renderer_->backward(w, grad);
    EXPECT_GT(std::abs(grad[gmf::kLogit]), 0.0f);
    const bool second_moved = std::any_of(grad.begin() + 11, grad.end(), [](float g) { return g != 0.0f; });
    EXPECT_EQ(second_moved, mode == MipMode::kSoftmax) << (mode == MipMode::kMax ? "hard" : "soft");
  }
}

// Buffers are kept and only grown between frames: a small frame after a large one and
// the large one again must not see stale tiles, ranges or counters. Each forward is
// deterministic (a fixed order of the terms per pixel: CUDA's stable sort, the CPU's
// amplitude buckets filled in Gaussian order), so the images are bit-identical.
TEST_P(SplatBackend, FramesOfDifferentSizesDoNotShareState) {
  const auto big = make_splat_scene(300, 73, 200, 150, 0.01, 0.05);
  const auto small = make_splat_scene(7, 74, 33, 17);
  const SplatSettings s;
  const std::vector<float> big_first = render(*renderer_, big, s);
  const std::int64_t big_entries = renderer_->stats().tile_entries;
  const std::vector<float> small_after_big = render(*renderer_, small, s);
  const std::vector<float> big_again = render(*renderer_, big, s);
  EXPECT_EQ(big_first, big_again);
  EXPECT_EQ(renderer_->stats().tile_entries, big_entries);
  auto fresh = fresh_renderer();
  EXPECT_EQ(render(*fresh, small, s), small_after_big);
}

// "SplatBackend.<Test>/Cpu", ".../Cuda" (-Wswitch names a new back end left out).
std::string backend_test_name(const ::testing::TestParamInfo<Backend>& info) {
  switch (info.param) {
    case Backend::kCpu:
      return "Cpu";
    case Backend::kCuda:
      return "Cuda";
  }
  return "Backend" + std::to_string(static_cast<int>(info.param));
}

// Two disjoint shares of a scene, rendered apart and combined as the MPI ranks of a
// distributed render combine them (render_views.hpp): hard by the max, bit for bit;
// soft by merging the softmax states, equal to the whole render to float rounding.
TEST_P(SplatBackend, SharesOfAModelCombineIntoTheWholeRender) {
  const testing::SplatScene scene = make_splat_scene(40, 91, 70, 45);
  const std::vector<float> all = to_float(scene.params);
  const std::size_t half = 11 * 17;  // 17 of the 40 Gaussians in the first share
  const std::vector<float> first(all.begin(), all.begin() + half), second(all.begin() + half, all.end());
  const std::size_t pixels = static_cast<std::size_t>(scene.K.width) * scene.K.height;
  for (const MipMode mode : {MipMode::kMax, MipMode::kSoftmax}) {
    SplatSettings settings;
    settings.mode = mode;
    std::vector<float> whole(pixels), a(pixels), b(pixels), m(pixels), S(pixels);
    renderer_->forward(all, scene.K, scene.view, settings, whole);
    std::vector<SoftPixel> merged(pixels);
    renderer_->forward(first, scene.K, scene.view, settings, a);
    if (mode == MipMode::kSoftmax) {
      renderer_->soft_state(m, S);
      for (std::size_t i = 0; i < pixels; ++i) merged[i] = {m[i], S[i], a[i]};
    }
    renderer_->forward(second, scene.K, scene.view, settings, b);
    if (mode == MipMode::kMax) {
      for (std::size_t i = 0; i < pixels; ++i) a[i] = std::max(a[i], b[i]);
      EXPECT_EQ(a, whole) << "hard MIP: the max of the shares is the whole render";
      EXPECT_THROW(renderer_->soft_state(m, S), std::logic_error);
      continue;
    }
    renderer_->soft_state(m, S);
    double worst = 0, peak = 0;
    int touched_by_both = 0;
    for (std::size_t i = 0; i < pixels; ++i) {
      if (merged[i].S > 0 && S[i] > 0) ++touched_by_both;
      const SoftPixel p = merge_soft_pixel(merged[i], {m[i], S[i], b[i]});
      worst = std::max(worst, static_cast<double>(std::abs(p.I - whole[i])));
      peak = std::max(peak, static_cast<double>(whole[i]));
    }
    EXPECT_GT(touched_by_both, 100) << "the shares must overlap for the merge to be tested";
    EXPECT_LT(worst, 1e-5 * peak) << "soft MIP merged from the shares vs rendered whole";
    // The merge is symmetric and leaves a pixel no share reaches untouched.
    const SoftPixel x{3.0f, 2.0f, 0.4f}, y{5.0f, 1.5f, 0.7f}, none{};
    EXPECT_NEAR(merge_soft_pixel(x, y).I, merge_soft_pixel(y, x).I, 1e-7);
    EXPECT_EQ(merge_soft_pixel(none, x).I, x.I);
    EXPECT_EQ(merge_soft_pixel(none, none).S, 0.0f);
  }
}

INSTANTIATE_TEST_SUITE_P(, SplatBackend, ::testing::Values(Backend::kCpu, Backend::kCuda), backend_test_name);

}  // namespace
}  // namespace hisnegs::splat
