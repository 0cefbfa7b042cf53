// SPDX-License-Identifier: Apache-2.0
// splat/background_floor: the floor table against the exact order statistic, chord
// lengths in voxels, the floor image, and the calibration of samples per voxel
// against the ray marcher, checked on a larger noise volume it never saw.
#include "splat/background_floor.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

#include "gmf/core/background.hpp"
#include "splat/raymarch.hpp"

namespace hisnegs::splat {
namespace {

// Poisson(0.6) counts / 255: op1's noisy recipe.
gmf::BackgroundModel poisson_model(double lambda) {
  gmf::BackgroundModel m;
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
  gmf::BackgroundModel m = poisson_model(0.6);
  m.samples_per_voxel = 0.8;
  const FloorTable table(m);
  for (const double L : {0.5, 1.0, 3.3, 17.0, 250.0, 1900.0, 5e5}) {
    const double exact = m.expected_max(0.8 * L);
    EXPECT_NEAR(table.at_voxels(L), exact, 1e-4 * exact) << L;
  }
  EXPECT_EQ(table.at_voxels(0.0), 0.0);
  EXPECT_TRUE(FloorTable(gmf::BackgroundModel{}).none());
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
  const std::vector<float> none =
      background_floor(FloorTable(gmf::BackgroundModel{}), frame, cams.intrinsics, cams.views[0]);
  for (const float v : none) EXPECT_EQ(v, 0.0f);
  const gmf::BackgroundModel m = poisson_model(0.6);
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
  const gmf::BackgroundModel voxels = poisson_model(0.6);
  gmf::BackgroundModel m = voxels;                                             // becomes what a ray samples, with its c
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

// With the same distribution in every region, the region floor is the table's.
TEST(RegionFloor, OneDistributionEverywhereIsTheTablesFloor) {
  gmf::BackgroundModel m = poisson_model(0.6);
  m.samples_per_voxel = 0.8;
  gmf::BackgroundField field;
  field.regions = gmf::BackgroundRegions::of({40, 30, 10}, 16);
  ASSERT_EQ(field.regions.count(), 3 * 2 * 1);
  field.merged = m;
  field.models.assign(6, m);
  const io::WorldFrame frame(40, 30, 10, Eigen::Vector3d(1.0, 0.75, 0.5));
  const RegionFloor floor(field, frame);
  const FloorTable table(m);
  std::mt19937_64 rng(3);
  std::normal_distribution<double> g(0.0, 1.0);
  int hits = 0;
  for (int i = 0; i < 400; ++i) {
    const Eigen::Vector3d origin = 3.0 * Eigen::Vector3d(g(rng), g(rng), g(rng)).normalized();
    const Eigen::Vector3d dir = (-origin + 0.4 * Eigen::Vector3d(g(rng), g(rng), g(rng))).normalized();
    const double expected = table.at_voxels(box_path_voxels(frame, origin, dir));
    const double got = floor.at(origin, dir);
    if (expected == 0.0) {
      EXPECT_EQ(got, 0.0);
      continue;
    }
    ++hits;
    // Half a grid interval of 11/255 / 511, and the table's 1e-4.
    EXPECT_NEAR(got, expected, 0.5 * m.values.back() / 511 + 1e-4 * expected) << i;
  }
  EXPECT_GT(hits, 200);
}

// A ray through two regions: the mean of the maximum of c L_A samples of A and
// c L_B of B, whose CDF is F_A^(c L_A) F_B^(c L_B) (exact integral of the step
// functions); one through a subtracted region alone: 0.
TEST(RegionFloor, TheMaximumOverTheRegionsCrossedHasTheProductOfTheirCdfs) {
  gmf::BackgroundModel a = poisson_model(0.6), b = poisson_model(2.5);
  a.samples_per_voxel = b.samples_per_voxel = 0.5;
  gmf::BackgroundField field;
  field.regions = gmf::BackgroundRegions::of({60, 20, 20}, 20);  // 3 x 1 x 1
  field.merged = a;
  field.models = {a, b, gmf::BackgroundModel{{0.0}, {1.0}, 0.5, 100}};
  const io::WorldFrame frame(60, 20, 20, Eigen::Vector3d(1.0, 1.0 / 3, 1.0 / 3));  // cubic voxels of 1/30
  const RegionFloor floor(field, frame);
  const auto exact = [&](double na, double nb) {
    std::vector<double> v = a.values;
    v.insert(v.end(), b.values.begin(), b.values.end());
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
    const auto cdf = [](const gmf::BackgroundModel& m, double x) {
      double F = 0;
      for (std::size_t i = 0; i < m.values.size() && m.values[i] <= x; ++i) F = m.cdf[i];
      return F;
    };
    double mean = 0;  // ∫ (1 − P(max <= x)) dx over the steps
    for (std::size_t i = 0; i + 1 < v.size(); ++i) {
      mean += (v[i + 1] - v[i]) * (1.0 - std::pow(cdf(a, v[i]), na) * std::pow(cdf(b, v[i]), nb));
    }
    return mean;
  };
  const double tolerance = 0.5 * b.values.back() / 511;
  // Along x through the middle: 20 voxels in each region.
  EXPECT_NEAR(floor.at({-3, 0.01, 0.01}, {1, 0, 0}), exact(0.5 * 20, 0.5 * 20), tolerance);
  // Along y inside region A alone, then B alone, then the subtracted region.
  EXPECT_NEAR(floor.at({-0.6, -3, 0.01}, {0, 1, 0}), exact(0.5 * 20, 0), tolerance);
  EXPECT_NEAR(floor.at({0.05, -3, 0.01}, {0, 1, 0}), exact(0, 0.5 * 20), tolerance);
  EXPECT_EQ(floor.at({0.7, -3, 0.01}, {0, 1, 0}), 0.0);
  // Oblique in x-y: y rises 1/6 per unit of x, so each region holds a chord of 20
  // voxels of x, sqrt(37) / 6 times as long; the subtracted third adds nothing.
  const Eigen::Vector3d d = Eigen::Vector3d(6, 1, 0).normalized();
  const Eigen::Vector3d origin = Eigen::Vector3d(-1.0, -0.2, 0.01) - 2.0 * d;
  const double n = 0.5 * 20 * std::sqrt(37.0) / 6.0;
  EXPECT_NEAR(floor.at(origin, d), exact(n, n), tolerance);
  EXPECT_EQ(floor.at({-3, 2, 0}, {1, 0, 0}), 0.0);  // misses the box
}

// A noise volume whose halves differ (Poisson 0.6 and 3.0 counts): its background by
// region, calibrated, predicts the marcher's MIP on each side; one distribution for
// the whole volume is off on both.
TEST(RegionFloor, ABackgroundByRegionPredictsTheMarchersMipOfTwoNoises) {
  io::Volume noise;
  noise.nx = noise.ny = 96;
  noise.nz = 24;
  noise.voxels.resize(noise.size());
  std::mt19937_64 rng(5);
  std::poisson_distribution<int> lo(0.6), hi(3.0);
  for (int z = 0; z < noise.nz; ++z)
    for (int y = 0; y < noise.ny; ++y)
      for (int x = 0; x < noise.nx; ++x) noise.at(x, y, z) = static_cast<float>(x < 48 ? lo(rng) : hi(rng)) / 255.0f;
  gmf::BackgroundOptions options;
  options.foreground_level = 0.9;  // all of it is background
  options.guard_voxels = 0;
  options.region_voxels = 48;
  gmf::BackgroundField field = gmf::estimate_background_field(noise, options);
  ASSERT_TRUE(field.regional());
  const io::WorldFrame frame(96, 96, 24, Eigen::Vector3d(1.0, 1.0, 0.5));
  const RaymarchOptions marching;
  (void)calibrate_background(field, frame, marching, 4);
  gmf::BackgroundModel merged = field.merged;  // calibrated with the field
  const BackgroundFloors regional(field, frame), single(merged, frame);
  ASSERT_TRUE(regional.regional());
  const RayMarcher marcher(noise, frame, marching);
  CameraOptions o;
  o.width = o.height = 64;
  const CameraSet cams = custom_orbit(o, {-70.0, 70.0}, {0.0, 180.0});  // near the z axis: rays stay in one half
  // A pixel's MIP is one draw; its floor is the mean. Compare means over 8 groups of
  // pixels ranked by the regional floor (from the low-noise side to the high one).
  std::vector<std::array<double, 3>> pixels;  // regional floor, single floor, MIP
  std::vector<float> image(64 * 64);
  for (const CameraView& view : cams.views) {
    marcher.render(cams.intrinsics, view, image);
    const std::vector<float> fr = regional(cams.intrinsics, view), fs = single(cams.intrinsics, view);
    for (std::size_t i = 0; i < image.size(); ++i) {
      if (fr[i] > 0.0f) pixels.push_back({fr[i], fs[i], image[i]});
    }
  }
  ASSERT_GT(pixels.size(), 4000u);
  std::sort(pixels.begin(), pixels.end());
  double worst_regional = 0, worst_single = 0;
  const std::size_t group = pixels.size() / 8;
  for (std::size_t g = 0; g < 8; ++g) {
    double r = 0, s1 = 0, mip = 0;
    for (std::size_t i = g * group; i < (g + 1) * group; ++i) {
      r += pixels[i][0];
      s1 += pixels[i][1];
      mip += pixels[i][2];
    }
    worst_regional = std::max(worst_regional, std::abs(r / mip - 1.0));
    worst_single = std::max(worst_single, std::abs(s1 / mip - 1.0));
  }
  EXPECT_LT(worst_regional, 0.06) << "the regional floor against the marcher's mean MIP";
  EXPECT_GT(worst_single, 3.0 * worst_regional) << "one floor for both halves: " << worst_single;
}

}  // namespace
}  // namespace hisnegs::splat
