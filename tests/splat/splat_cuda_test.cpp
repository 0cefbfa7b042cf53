// The CUDA splatting back end, through the public SplatRenderer interface (so the
// adapter in splat_renderer.cpp is covered too): forward and backward against the
// double reference and against the TBB back end, state reuse across frames, the
// skip counter and timings. Every GPU test skips when no CUDA device is usable.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

#include "splat/backend.hpp"
#include "splat/splat_reference.hpp"
#include "splat/splat_renderer.hpp"
#include "tests/splat/splat_test_scenes.hpp"
#if HISNEGS_HAVE_CUDA
#include "splat/cuda/splat_cuda.hpp"
#endif

namespace hisnegs::splat {
namespace {

using testing::boundary_flip_bound;
using testing::count_far;
using testing::large_scene;
using testing::largest_per_kind;
using testing::make_splat_scene;
using testing::max_abs_diff;
using testing::random_weights;
using testing::render;
using testing::to_float;

// GPU tests skip (not fail) on machines without a usable device (STYLE "Differentiable code").
class SplatCuda : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string why = testing::why_backend_untestable(Backend::kCuda);
    if (!why.empty()) GTEST_SKIP() << why;
  }
};

// Float math against double: values lie in [0, 1] and each pixel is a softmax-weighted
// mean of at most a few dozen terms whose float rounding (projection, q, exp, the
// online sums) is ~1e-6, so 1e-4 absolute leaves ample headroom. The cutoff is huge so
// no pixel sits on the δ boundary, where float and double may decide q <= δ
// differently (a jump of up to a e^-8); skipping is off so the sums are complete.
TEST_F(SplatCuda, SoftForwardMatchesReference) {
  auto renderer = make_splat_renderer(Backend::kCuda);
  for (std::uint64_t seed : {51u, 52u}) {
    const auto scene = make_splat_scene(20, seed, 64, 48);  // 4 x 3 tiles
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    for (float beta : {50.0f, 8.0f}) {
      SplatSettings s;
      s.beta = beta;
      s.cutoff = 1e6f;
      s.skip_log_weight = 0.0f;
      const std::vector<double> ref = render_reference(scene.params, view, s);
      const std::vector<float> img = render(*renderer, scene, s);
      EXPECT_LT(max_abs_diff(img, ref), 1e-4) << "seed " << seed << " beta " << beta;
      EXPECT_EQ(renderer->stats().visible, 20);
    }
  }
}

// Hard MIP is a max of float-evaluated terms: ~1e-6 from the double max (1e-4 as above).
TEST_F(SplatCuda, HardForwardMatchesReference) {
  auto renderer = make_splat_renderer(Backend::kCuda);
  for (std::uint64_t seed : {53u, 54u}) {
    const auto scene = make_splat_scene(20, seed, 70, 45);  // a partial tile column and row
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    SplatSettings s;
    s.mode = MipMode::kHard;
    s.cutoff = 1e6f;
    const std::vector<double> ref = render_reference(scene.params, view, s);
    const std::vector<float> img = render(*renderer, scene, s);
    EXPECT_LT(max_abs_diff(img, ref), 1e-4) << "seed " << seed;
  }
}

// With the default δ = 16 the tile rectangles matter (a Gaussian cut short by a wrong
// rectangle would be off by O(a)). Only pixels where a term sits on the δ boundary may
// differ by more than rounding, by at most boundary_flip_bound, and such pixels are rare
// (a float q lands within its rounding of δ on ~1e-6 of the boundary pairs).
TEST_F(SplatCuda, ForwardMatchesReferenceAtDefaultCutoff) {
  auto renderer = make_splat_renderer(Backend::kCuda);
  const auto scene = make_splat_scene(40, 55, 64, 48);
  const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
  for (MipMode mode : {MipMode::kSoft, MipMode::kHard}) {
    SplatSettings s;
    s.mode = mode;
    s.skip_log_weight = 0.0f;
    const std::vector<double> ref = render_reference(scene.params, view, s);
    const std::vector<float> img = render(*renderer, scene, s);
    EXPECT_LT(max_abs_diff(img, ref), boundary_flip_bound(s) + 1e-4) << "hard " << (mode == MipMode::kHard);
    EXPECT_LE(count_far(img, ref, 1e-4), static_cast<int>(0.01 * img.size())) << "hard " << (mode == MipMode::kHard);
    EXPECT_GT(renderer->stats().visible, 0);
    EXPECT_GE(renderer->stats().tile_entries, renderer->stats().visible);
  }
}

// Backward against the reference: both chain the same per-pixel terms through the
// same splat_math.hpp functions. The CUDA sums are float (per block, then atomicAdd
// over tiles) with ~1e-6 relative rounding, so each gradient is compared relative to
// the largest gradient of its parameter kind: 1e-3. The cutoff is huge for the
// reason above (a boundary term would also move the gradient).
TEST_F(SplatCuda, BackwardMatchesReference) {
  auto renderer = make_splat_renderer(Backend::kCuda);
  for (std::uint64_t seed : {61u, 62u}) {
    const auto scene = make_splat_scene(20, seed, 64, 48);
    const ViewParams<double> view = make_splat_view<double>(scene.K, scene.view);
    SplatSettings s;
    s.cutoff = 1e6f;
    s.skip_log_weight = 0.0f;
    s.beta = seed == 61 ? 50.0f : 8.0f;
    const std::vector<double> w = random_weights(static_cast<std::size_t>(scene.K.width) * scene.K.height, seed);
    std::vector<double> screen_ref;
    const std::vector<double> ref = render_reference_backward(scene.params, view, s, w, &screen_ref);
    render(*renderer, scene, s);
    std::vector<float> grad(scene.params.size(), 0.0f), screen(scene.params.size() / 11, 0.0f);
    renderer->backward(to_float(w), grad, screen);
    const std::vector<double> largest = largest_per_kind(ref);
    for (std::size_t i = 0; i < ref.size(); ++i) {
      EXPECT_LT(std::abs(grad[i] - ref[i]), 1e-3 * largest[i % 11] + 1e-9)
          << "seed " << seed << " param " << i << " (kind " << i % 11 << "): cuda " << grad[i] << " ref " << ref[i];
    }
    for (std::size_t k = 0; k < screen.size(); ++k) {
      EXPECT_NEAR(screen[k], screen_ref[k], 1e-3 * screen_ref[k] + 1e-6) << "seed " << seed << " Gaussian " << k;
    }
  }
}

// backward() adds into the caller's arrays: two calls give twice one call. The float
// atomics may add in another order each call, hence 1e-5 of the largest gradient.
TEST_F(SplatCuda, BackwardAccumulates) {
  auto renderer = make_splat_renderer(Backend::kCuda);
  const auto scene = make_splat_scene(10, 63, 48, 32);
  render(*renderer, scene, SplatSettings{});
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

// CUDA and TBB evaluate the same float math on the same (pixel, Gaussian) pairs in
// amplitude-descending order (exact on CUDA, 1024 buckets on the CPU); they differ
// only by rounding (summation order, FMA contraction, exp implementations) of ~1e-6.
// With δ = 1e6 every tile lists all 2000 Gaussians (8 shared-memory batches, the last
// one partial) and no pixel is near the boundary: 1e-4 everywhere. With the default
// δ = 16 (real tile rectangles) a term within an ulp or two of q = δ may be decided
// differently (measured on the CPU: moving δ by 50 ulps changes 2-3 of the 65536
// pixels, by < 8e-4), so there all pixels are within boundary_flip_bound and all but
// 0.1% within 1e-4. Skipping is on (default), as in training; the terms it drops weigh
// < e^-20 of their pixel's max on both sides. Visibility is the same float test but a
// Gaussian whose extent ends within an ulp of the border may be decided differently
// (at most a couple), and so may tile rectangles (0.1% of the pairs).
TEST_F(SplatCuda, ForwardMatchesCpuBackEnd) {
  auto cuda = make_splat_renderer(Backend::kCuda);
  auto cpu = make_splat_renderer(Backend::kCpu);
  const auto scene = large_scene();
  for (float cutoff : {1e6f, 16.0f}) {
    for (MipMode mode : {MipMode::kSoft, MipMode::kHard}) {
      SplatSettings s;
      s.mode = mode;
      s.cutoff = cutoff;
      const std::vector<float> a = render(*cuda, scene, s);
      const std::vector<float> b = render(*cpu, scene, s);
      const std::string what = "cutoff " + std::to_string(cutoff) + " hard " + std::to_string(mode == MipMode::kHard);
      if (cutoff > 1e5f) {
        EXPECT_LT(max_abs_diff(a, b), 1e-4) << what;
      } else {
        EXPECT_LT(max_abs_diff(a, b), boundary_flip_bound(s) + 1e-4) << what;
        EXPECT_LE(count_far(a, b, 1e-4), static_cast<int>(0.001 * a.size())) << what;
      }
      EXPECT_NEAR(cuda->stats().visible, cpu->stats().visible, 2) << what;
      EXPECT_NEAR(double(cuda->stats().tile_entries), double(cpu->stats().tile_entries),
                  1e-3 * double(cpu->stats().tile_entries))
          << what;
    }
  }
}

// Gradients against the TBB back end on the large scene, each relative to the largest
// of its kind: 1e-3 at δ = 1e6 (float sums as in BackwardMatchesReference); 2e-3 at the
// default δ, where a boundary term decided differently also moves its Gaussian's sums
// (measured on the CPU: moving δ by 50 ulps changes gradients by < 5e-4 of their kind's
// largest).
TEST_F(SplatCuda, BackwardMatchesCpuBackEnd) {
  auto cuda = make_splat_renderer(Backend::kCuda);
  auto cpu = make_splat_renderer(Backend::kCpu);
  const auto scene = large_scene();
  const std::vector<float> w = to_float(random_weights(256 * 256, 72));
  const std::size_t n = scene.params.size();
  for (float cutoff : {1e6f, 16.0f}) {
    SplatSettings s;
    s.cutoff = cutoff;
    const double tolerance = cutoff > 1e5f ? 1e-3 : 2e-3;
    std::vector<float> grad_cuda(n, 0.0f), grad_cpu(n, 0.0f), screen_cuda(n / 11, 0.0f), screen_cpu(n / 11, 0.0f);
    render(*cuda, scene, s);
    cuda->backward(w, grad_cuda, screen_cuda);
    render(*cpu, scene, s);
    cpu->backward(w, grad_cpu, screen_cpu);
    const std::vector<double> largest = largest_per_kind(std::vector<double>(grad_cpu.begin(), grad_cpu.end()));
    // The worst gradient, relative to its kind's largest (22000 parameters: one message).
    double worst = 0;
    std::size_t worst_at = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double rel = std::abs(grad_cuda[i] - grad_cpu[i]) / (largest[i % 11] + 1e-30);
      if (rel > worst) {
        worst = rel;
        worst_at = i;
      }
    }
    EXPECT_LT(worst, tolerance) << "cutoff " << cutoff << " param " << worst_at << " (kind " << worst_at % 11
                                << "): cuda " << grad_cuda[worst_at] << " cpu " << grad_cpu[worst_at];
    const double screen_largest = *std::max_element(screen_cpu.begin(), screen_cpu.end());
    EXPECT_LT(max_abs_diff(screen_cuda, screen_cpu), tolerance * screen_largest) << "cutoff " << cutoff;
  }
}

// Buffers are kept and only grown between frames: a small frame after a large one and
// the large one again must not see stale tiles, ranges or counters. Each forward is
// deterministic (stable sort, fixed per-pixel order), so the images are bit-identical.
TEST_F(SplatCuda, FramesOfDifferentSizesDoNotShareState) {
  auto renderer = make_splat_renderer(Backend::kCuda);
  const auto big = make_splat_scene(300, 73, 200, 150, 0.01, 0.05);
  const auto small = make_splat_scene(7, 74, 33, 17);
  const SplatSettings s;
  const std::vector<float> big_first = render(*renderer, big, s);
  const std::int64_t big_entries = renderer->stats().tile_entries;
  const std::vector<float> small_after_big = render(*renderer, small, s);
  const std::vector<float> big_again = render(*renderer, big, s);
  EXPECT_EQ(big_first, big_again);
  EXPECT_EQ(renderer->stats().tile_entries, big_entries);
  auto fresh = make_splat_renderer(Backend::kCuda);
  EXPECT_EQ(render(*fresh, small, s), small_after_big);
}

// No Gaussians, or all behind the camera: a black image, nothing visible, and a
// backward that adds nothing.
TEST_F(SplatCuda, EmptyAndCulledScenesRenderBlack) {
  auto renderer = make_splat_renderer(Backend::kCuda);
  auto scene = make_splat_scene(5, 75, 40, 32);
  const Eigen::Vector3d C = -scene.view.R_cam_from_world.transpose() * scene.view.t_cam_from_world;
  const Eigen::Vector3d forward = scene.view.R_cam_from_world.row(2).transpose();
  for (int k = 0; k < 5; ++k) {
    for (int a = 0; a < 3; ++a) scene.params[11 * k + a] = C[a] - 0.5 * forward[a];
  }
  const std::vector<float> img = render(*renderer, scene, SplatSettings{});
  EXPECT_EQ(*std::max_element(img.begin(), img.end()), 0.0f);
  EXPECT_EQ(renderer->stats().visible, 0);
  EXPECT_EQ(renderer->stats().tile_entries, 0);
  std::vector<float> grad(scene.params.size(), 0.0f);
  renderer->backward(std::vector<float>(img.size(), 1.0f), grad);
  EXPECT_EQ(*std::max_element(grad.begin(), grad.end()), 0.0f);
  EXPECT_EQ(*std::min_element(grad.begin(), grad.end()), 0.0f);

  std::vector<float> none_img(img.size(), 1.0f);
  renderer->forward(std::span<const float>(), scene.K, scene.view, SplatSettings{}, none_img);
  EXPECT_EQ(*std::max_element(none_img.begin(), none_img.end()), 0.0f);
}

// Skipping drops only terms whose weight is below e^-skip of the pixel's running max,
// so the image moves by less than (Gaussians) e^-skip; the dropped terms are counted.
TEST_F(SplatCuda, SkippedTermsAreCountedAndNegligible) {
  auto renderer = make_splat_renderer(Backend::kCuda);
  auto scene = make_splat_scene(60, 76, 64, 48, 0.08, 0.2);
  // A few bright Gaussians over many dim ones so that skipping happens.
  for (int k = 0; k < 60; ++k) scene.params[11 * k + 10] = k < 6 ? 3.0 : -2.5;
  SplatSettings exact;
  exact.skip_log_weight = 0.0f;
  const std::vector<float> a = render(*renderer, scene, exact);
  EXPECT_EQ(renderer->stats().skipped_terms, 0);
  SplatSettings skip = exact;
  skip.skip_log_weight = 8.0f;
  const std::vector<float> b = render(*renderer, scene, skip);
  EXPECT_GT(renderer->stats().skipped_terms, 0);
  EXPECT_LT(max_abs_diff(a, b), 60 * std::exp(-8.0) + 1e-6);
}

TEST_F(SplatCuda, BackwardNeedsASoftForward) {
  auto renderer = make_splat_renderer(Backend::kCuda);
  const auto scene = make_splat_scene(3, 77, 16, 16);
  SplatSettings hard;
  hard.mode = MipMode::kHard;
  const std::vector<float> img = render(*renderer, scene, hard);
  std::vector<float> grad(scene.params.size(), 0.0f);
  EXPECT_THROW(renderer->backward(img, grad), std::logic_error);
}

#if HISNEGS_HAVE_CUDA
// The device-work timings (CUDA events, without host copies) are measured and reported.
TEST_F(SplatCuda, ReportsDeviceTimes) {
  cuda::CudaSplatter splatter;
  const auto scene = large_scene();
  const std::vector<float> p = to_float(scene.params);
  const std::size_t count = p.size() / gmf::kGaussianParamCount;
  std::vector<float> img(256 * 256), grad(p.size(), 0.0f);
  splatter.forward(p.data(), count, make_splat_view<float>(scene.K, scene.view), SplatSettings{}, img.data());
  EXPECT_GT(splatter.last_forward_ms(), 0.0);
  EXPECT_GT(splatter.visible(), 0);
  splatter.backward(std::vector<float>(img.size(), 1.0f).data(), grad.data(), nullptr);
  EXPECT_GT(splatter.last_backward_ms(), 0.0);
}
#endif

// Without a device the CUDA renderer cannot be made; this is a clear exception, not a
// crash later (runs on machines without a GPU; skips where one is present).
TEST(SplatCudaWithoutDevice, RendererCannotBeMade) {
  if (cuda_device_info().available) GTEST_SKIP() << "a CUDA device is present: " << cuda_device_info().name;
  EXPECT_THROW((void)make_splat_renderer(Backend::kCuda), std::runtime_error);
}

}  // namespace
}  // namespace hisnegs::splat
