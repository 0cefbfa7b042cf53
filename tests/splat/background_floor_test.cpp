// SPDX-License-Identifier: Apache-2.0
// splat/background_floor: the floor table against the exact order statistic, chord
// lengths in voxels, the floor image, and the calibration of samples per voxel
// against the ray marcher, checked on a larger noise volume it never saw.
#include "splat/background_floor.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "splat/raymarch.hpp"

namespace hisnegs::splat {
namespace {

// Poisson(0.6) counts / 255: op1's noisy recipe.
io::BackgroundModel poisson_model(double lambda) {
  io::BackgroundModel m;
  double p = std::exp(-lambda), cdf = 0;
  for (int k = 0; k < 12; ++k) {
    cdf += p;
    m.values.push_back(k / 255.0);
    m.cdf.push_back(k == 11 ? 1.0 : cdf);
    p *= lambda / (k + 1);
  }
  return m;
}

TEST(BackgroundFloor, TableMatchesTheExactOrderStatistic) {
  io::BackgroundModel m = poisson_model(0.6);
  m.samples_per_voxel = 0.8;
  const FloorTable table(m);
  for (const double L : {0.5, 1.0, 3.3, 17.0, 250.0, 1900.0, 5e5}) {
    const double exact = m.expected_max(0.8 * L);
    EXPECT_NEAR(table.at_voxels(L), exact, 1e-4 * exact) << L;
  }
  EXPECT_EQ(table.at_voxels(0.0), 0.0);
  EXPECT_TRUE(FloorTable(io::BackgroundModel{}).none());
}

TEST(BackgroundFloor, ChordsAreMeasuredInVoxels) {
  const io::WorldFrame frame(40, 30, 10, Eigen::Vector3d(1.0, 0.75, 0.5));  // voxels of 0.05 x 0.05 x 0.1
  EXPECT_NEAR(box_path_voxels(frame, {-3, 0, 0}, {1, 0, 0}), 40.0, 1e-9);
  EXPECT_NEAR(box_path_voxels(frame, {0, 0, -3}, {0, 0, 1}), 10.0, 1e-9);
  EXPECT_EQ(box_path_voxels(frame, {-3, 0, 0}, {-1, 0, 0}), 0.0);  // pointing away
  EXPECT_EQ(box_path_voxels(frame, {-3, 2, 0}, {1, 0, 0}), 0.0);   // passing by
  const Eigen::Vector3d d = Eigen::Vector3d(1, 0, 1).normalized();
  // Through the centre at 45° in x-z: leaves through z = ±0.5 first, world chord
  // sqrt(2) along the diagonal from (-0.5, 0, -0.5): 20 voxels in x, 10 in z.
  EXPECT_NEAR(box_path_voxels(frame, Eigen::Vector3d(-0.5, 0, -0.5) - 2 * d, d), std::hypot(20.0, 10.0), 1e-9);
}

TEST(BackgroundFloor, FloorImageIsZeroWithoutABackgroundAndOffTheBox) {
  const io::WorldFrame frame(32, 32, 16, Eigen::Vector3d(1.0, 1.0, 0.5));
  CameraOptions o;
  o.width = 40;
  o.height = 30;
  const CameraSet cams = custom_orbit(o, {20.0}, {30.0});
  const std::vector<float> none = background_floor(FloorTable(io::BackgroundModel{}), frame, cams.intrinsics,
                                                   cams.views[0]);
  for (const float v : none) EXPECT_EQ(v, 0.0f);
  const io::BackgroundModel m = poisson_model(0.6);
  const std::vector<float> floor = background_floor(FloorTable(m), frame, cams.intrinsics, cams.views[0]);
  ASSERT_EQ(floor.size(), 40u * 30u);
  EXPECT_EQ(floor[0], 0.0f);  // the corner ray misses the box
  const float centre = floor[15 * 40 + 20];
  EXPECT_GT(centre, m.mean());
  EXPECT_LE(centre, m.values.back());
}

// The calibrated c predicts the mean MIP of i.i.d. noise for the marcher, also on
// a larger, anisotropic volume (longer chords) than the calibration's.
TEST(BackgroundFloor, CalibrationPredictsTheMarchersMipOfNoise) {
  const io::BackgroundModel voxels = poisson_model(0.6);
  io::BackgroundModel m = voxels;  // becomes what a ray samples, with its c
  const io::WorldFrame stack(160, 160, 40, Eigen::Vector3d(1.0, 1.0, 0.75));  // z voxels 3x the xy ones
  const RaymarchOptions options;
  const FloorCalibration cal = calibrate_background(m, stack, options, 4);
  EXPECT_GT(cal.rays, 20000);
  EXPECT_GT(m.values.size(), voxels.values.size());  // interpolation makes values between the counts
  EXPECT_LT(cal.worst_relative_error, 0.05);
  EXPECT_GT(m.samples_per_voxel, 0.1);
  EXPECT_LT(m.samples_per_voxel, 3.0);

  io::Volume noise;
  noise.nx = noise.ny = 120;
  noise.nz = 30;
  noise.voxels.resize(noise.size());
  std::mt19937_64 rng(99);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (float& v : noise.voxels) v = static_cast<float>(voxels.quantile(u(rng)));
  const io::WorldFrame frame(120, 120, 30, Eigen::Vector3d(1.0, 1.0, 0.75));
  const RayMarcher marcher(noise, frame, options);
  CameraOptions o;
  o.width = o.height = 64;
  const CameraSet cams = custom_orbit(o, {-40.0, 10.0, 70.0}, {0.0, 100.0, 200.0});
  const FloorTable table(m);
  double sum_mip = 0, sum_floor = 0;
  std::vector<float> image(64 * 64);
  for (const CameraView& view : cams.views) {
    marcher.render(cams.intrinsics, view, image);
    const std::vector<float> floor = background_floor(table, frame, cams.intrinsics, view);
    for (std::size_t i = 0; i < image.size(); ++i) {
      if (floor[i] == 0.0f) continue;
      sum_mip += image[i];
      sum_floor += floor[i];
    }
  }
  ASSERT_GT(sum_mip, 0.0);
  EXPECT_NEAR(sum_floor / sum_mip, 1.0, 0.05);
}

}  // namespace
}  // namespace hisnegs::splat
