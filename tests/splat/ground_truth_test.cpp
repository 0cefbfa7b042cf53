// SPDX-License-Identifier: Apache-2.0
// render_ground_truth over camera sets: CPU result equals per-view rendering,
// and the CUDA back end equals the CPU (skips without a GPU).
#include "splat/ground_truth.hpp"

#include <gtest/gtest.h>

#include <random>

#include "splat/raymarch.hpp"

namespace hisnegs::splat {
namespace {

io::Volume random_volume(int nx, int ny, int nz, std::uint64_t seed) {
  io::Volume v;
  v.nx = nx;
  v.ny = ny;
  v.nz = nz;
  v.voxels.assign(v.size(), 0.0f);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (float& x : v.voxels) x = u(rng) < 0.02 ? u(rng) : 0.0f;
  return v;
}

TEST(GroundTruth, CpuStackHoldsEveryViewInOrder) {
  const io::Volume v = random_volume(40, 36, 12, 1);
  const io::WorldFrame frame(v.nx, v.ny, v.nz, Eigen::Vector3d(1.0, 0.9, 0.3));
  CameraOptions co;
  co.width = 32;
  co.height = 24;
  const CameraSet cams = custom_orbit(co, {-20, 40}, {0, 100, 250});
  const MipStack stack = render_ground_truth(v, frame, cams, RaymarchOptions{}, Backend::kCpu);
  ASSERT_EQ(stack.views, 6);
  ASSERT_EQ(stack.seconds_per_view.size(), 6u);
  const RayMarcher m(v, frame, RaymarchOptions{});
  std::vector<float> img(32 * 24);
  for (int i = 0; i < 6; ++i) {
    m.render(cams.intrinsics, cams.views[i], img);
    EXPECT_TRUE(std::equal(img.begin(), img.end(), stack.view(i).begin())) << i;
  }
}

TEST(GroundTruth, CudaEqualsCpu) {
  if (!cuda_device_info().available) GTEST_SKIP() << "no CUDA device: " << cuda_device_info().reason;
  const io::Volume v = random_volume(97, 83, 41, 2);
  const io::WorldFrame frame(v.nx, v.ny, v.nz, Eigen::Vector3d(1.0, 83.0 / 97, 41.0 / 97));
  CameraOptions co;
  co.width = 128;
  co.height = 96;
  const CameraSet cams = custom_orbit(co, {-90, -30, 0, 45, 90}, {0, 77, 200});
  for (auto mode : {RaymarchMode::kExact, RaymarchMode::kReport}) {
    RaymarchOptions ro;
    ro.mode = mode;
    const MipStack cpu = render_ground_truth(v, frame, cams, ro, Backend::kCpu);
    const MipStack gpu = render_ground_truth(v, frame, cams, ro, Backend::kCuda);
    ASSERT_EQ(gpu.backend, Backend::kCuda);
    double worst = 0;
    for (std::size_t i = 0; i < cpu.pixels.size(); ++i) {
      worst = std::max(worst, static_cast<double>(std::abs(cpu.pixels[i] - gpu.pixels[i])));
    }
    // Same kernel source; only FMA contraction and the device's float rounding differ.
    EXPECT_LT(worst, 1e-4) << (mode == RaymarchMode::kExact ? "exact" : "report");
  }
}

}  // namespace
}  // namespace hisnegs::splat
