// SPDX-License-Identifier: Apache-2.0
// Ground truth of a stack read by bricks (render_ground_truth_streamed) equals the
// whole-stack march bit for bit: exact and report modes, raw values normalized on
// the way, cores from three voxels to larger than the stack, anisotropic boxes and
// views from every side (rays that cross many brick faces).
#include "splat/streamed_ground_truth.hpp"

#include <gtest/gtest.h>

#include <random>

#include "io/volume_source.hpp"

namespace hisnegs::splat {
namespace {

TEST(StreamedGroundTruth, BricksGiveTheWholeMarchBitForBit) {
  io::Volume raw;
  raw.nx = 37, raw.ny = 29, raw.nz = 13;
  raw.stored_as = io::SampleType::kUint16;
  raw.voxels.assign(raw.size(), 0.0f);
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  for (float& x : raw.voxels) x = u(rng) < 0.05f ? std::floor(u(rng) * 3000.0f) : 0.0f;
  raw.voxels[5] = 3000.0f;  // the maximum
  const auto source = io::memory_source(raw);
  io::Volume v = raw;
  io::normalize(v, {});
  const io::WorldFrame frame(v.nx, v.ny, v.nz, Eigen::Vector3d(1.0, 0.78, 0.55));
  CameraOptions co;
  co.width = 40;
  co.height = 30;
  const CameraSet cams = custom_orbit(co, {-80, 0, 90}, {0, 137, 270});
  for (const RaymarchMode mode : {RaymarchMode::kExact, RaymarchMode::kReport}) {
    RaymarchOptions rm;
    rm.mode = mode;
    const MipStack whole = render_ground_truth(v, frame, cams, rm, Backend::kCpu);
    for (const int core : {3, 8, 64}) {
      int bricks = 0;
      const MipStack streamed = render_ground_truth_streamed(*source, v.normalization, frame, cams, rm, core,
                                                             [&](int, int total) { bricks = total; });
      ASSERT_EQ(streamed.pixels.size(), whole.pixels.size());
      std::size_t differ = 0;
      for (std::size_t i = 0; i < whole.pixels.size(); ++i) differ += streamed.pixels[i] != whole.pixels[i];
      EXPECT_EQ(differ, 0u) << "core " << core << " mode " << static_cast<int>(mode) << " (" << bricks << " bricks)";
    }
  }
}

}  // namespace
}  // namespace hisnegs::splat
