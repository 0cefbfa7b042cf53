// SPDX-License-Identifier: Apache-2.0
// Tests of io/volume: normalization, statistics, aspect scales (Eq. 9), the
// CONVENTIONS index<->world map and trilinear sampling against hand-computed values.
#include "io/volume.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "io/error.hpp"

namespace hisnegs::io {
namespace {

Volume ramp_volume(int nx, int ny, int nz) {
  Volume v;
  v.nx = nx;
  v.ny = ny;
  v.nz = nz;
  v.source = "ramp";
  v.voxels.resize(v.size());
  for (int z = 0; z < nz; ++z)
    for (int y = 0; y < ny; ++y)
      for (int x = 0; x < nx; ++x) v.at(x, y, z) = static_cast<float>(x + 10 * y + 100 * z);
  return v;
}

TEST(VolumeAspect, ReportStackByEq9) {
  // The report's (Z, Y, X) = (100, 647, 813) stack: (1, 0.796, 0.123).
  const Eigen::Vector3d a = aspect_scales(813, 647, 100, VoxelSpacing{}, AspectMode::kShape);
  EXPECT_DOUBLE_EQ(a.x(), 1.0);
  EXPECT_NEAR(a.y(), 0.796, 5e-4);
  EXPECT_NEAR(a.z(), 0.123, 5e-4);
}

TEST(VolumeAspect, PhysicalUsesSpacing) {
  VoxelSpacing s;
  s.um = {0.5, 0.5, 2.0};
  const Eigen::Vector3d a = aspect_scales(100, 50, 10, s, AspectMode::kPhysical);
  // extents 50, 25, 20 um -> /50
  EXPECT_DOUBLE_EQ(a.x(), 1.0);
  EXPECT_DOUBLE_EQ(a.y(), 0.5);
  EXPECT_DOUBLE_EQ(a.z(), 0.4);
  // With unknown (1 um) spacing both modes agree.
  EXPECT_TRUE(aspect_scales(100, 50, 10, VoxelSpacing{}, AspectMode::kPhysical)
                  .isApprox(aspect_scales(100, 50, 10, VoxelSpacing{}, AspectMode::kShape)));
}

TEST(VolumeWorldFrame, VoxelCentresAndRoundTrip) {
  const WorldFrame f(4, 2, 8, Eigen::Vector3d(1.0, 0.5, 0.25));
  // x = a (2 (i + 0.5) / N - 1): i = 0 -> 1 * (0.25 - 1) = -0.75; i = 3 -> 0.75.
  EXPECT_TRUE(f.world_from_index({0, 0, 0}).isApprox(Eigen::Vector3d(-0.75, -0.25, -0.21875)));
  EXPECT_TRUE(f.world_from_index({3, 1, 7}).isApprox(Eigen::Vector3d(0.75, 0.25, 0.21875)));
  // Box faces sit half a voxel beyond the outer centres.
  EXPECT_NEAR(f.index_from_world({-1.0, -0.5, -0.25}).x(), -0.5, 1e-12);
  EXPECT_NEAR(f.index_from_world({1.0, 0.5, 0.25}).z(), 7.5, 1e-12);
  const Eigen::Vector3d p(0.123, -0.321, 0.2);
  EXPECT_TRUE(f.world_from_index(f.index_from_world(p)).isApprox(p, 1e-14));
  EXPECT_TRUE(f.voxel_size().isApprox(Eigen::Vector3d(0.5, 0.5, 0.0625)));
}

TEST(VolumeTrilinear, HandComputedValues) {
  const Volume v = ramp_volume(4, 3, 2);
  const WorldFrame f(4, 3, 2, Eigen::Vector3d(1.0, 0.75, 0.5));
  // At a voxel centre: the voxel's value.
  EXPECT_FLOAT_EQ(sample_trilinear(v, f, f.world_from_index({2, 1, 1})), 2 + 10 + 100);
  // Half way between (1,0,0) and (2,1,1): the ramp is linear, so 1.5 + 5 + 50.
  EXPECT_NEAR(sample_trilinear(v, f, f.world_from_index({1.5, 0.5, 0.5})), 56.5, 1e-4);
  // Index (0.25, 1.75, 0.5): 0.25 + 17.5 + 50.
  EXPECT_NEAR(sample_trilinear(v, f, f.world_from_index({0.25, 1.75, 0.5})), 67.75, 1e-4);
  // Between the last centre and the box face the index clamps to N-1.
  EXPECT_FLOAT_EQ(sample_trilinear(v, f, f.world_from_index({3.4, 2.0, 1.0})), 3 + 20 + 100);
  // Outside the box: 0, even right next to a bright face.
  EXPECT_EQ(sample_trilinear(v, f, Eigen::Vector3d(1.0001, 0.0, 0.0)), 0.0f);
  EXPECT_EQ(sample_trilinear(v, f, Eigen::Vector3d(0.0, 0.0, -0.5001)), 0.0f);
  // On the face itself: inside (clamped to the outer centre).
  EXPECT_FLOAT_EQ(sample_trilinear(v, f, Eigen::Vector3d(1.0, 0.75, 0.5)), 3 + 20 + 100);
}

TEST(VolumeNormalize, MinMaxMapsToUnitRange) {
  Volume v = ramp_volume(5, 4, 3);
  normalize(v, NormalizationOptions{});
  EXPECT_EQ(v.normalization.method, NormalizationMethod::kMinMax);
  EXPECT_DOUBLE_EQ(v.normalization.raw_lo, 0.0);
  EXPECT_DOUBLE_EQ(v.normalization.raw_hi, 4 + 30 + 200);
  EXPECT_FLOAT_EQ(v.at(0, 0, 0), 0.0f);
  EXPECT_FLOAT_EQ(v.at(4, 3, 2), 1.0f);
  EXPECT_NEAR(v.at(2, 1, 1), 112.0 / 234.0, 1e-6);
}

TEST(VolumeNormalize, PercentileClipsAndCounts) {
  Volume v;
  v.nx = 100;
  v.ny = 1;
  v.nz = 1;
  v.voxels.resize(100);
  for (int i = 0; i < 100; ++i) v.voxels[i] = static_cast<float>(i);
  NormalizationOptions o;
  o.method = NormalizationMethod::kPercentile;
  o.percentile_lo = 10;
  o.percentile_hi = 90;
  normalize(v, o);
  // Order statistics at positions 9.9 and 89.1 of 0..99.
  EXPECT_NEAR(v.normalization.raw_lo, 9.9, 1e-9);
  EXPECT_NEAR(v.normalization.raw_hi, 89.1, 1e-9);
  EXPECT_EQ(v.voxels.front(), 0.0f);
  EXPECT_EQ(v.voxels.back(), 1.0f);
  EXPECT_EQ(v.normalization.clipped_voxels, 20);
}

TEST(VolumeNormalize, ConstantVolumeIsAnError) {
  Volume v = ramp_volume(3, 3, 3);
  std::fill(v.voxels.begin(), v.voxels.end(), 7.0f);
  v.source = "const.tif";
  try {
    normalize(v, NormalizationOptions{});
    FAIL() << "expected InputError";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("const.tif"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("constant"), std::string::npos);
  }
}

TEST(VolumeNormalize, NonFiniteIsAnErrorNamingTheVoxel) {
  for (float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity()}) {
    Volume v = ramp_volume(4, 3, 2);
    v.at(1, 2, 1) = bad;
    EXPECT_THROW(
        {
          try {
            normalize(v, NormalizationOptions{});
          } catch (const InputError& e) {
            EXPECT_NE(std::string(e.what()).find("x=1, y=2, z=1"), std::string::npos) << e.what();
            throw;
          }
        },
        InputError);
  }
}

// Found by fuzzing (fuzz_tiff): a float stack spanning more than the float range
// made v - lo and hi - lo overflow to inf, and normalized voxels NaN.
TEST(VolumeNormalize, RangeWiderThanFloatStaysInUnitInterval) {
  const float big = std::numeric_limits<float>::max();
  for (NormalizationMethod method : {NormalizationMethod::kMinMax, NormalizationMethod::kPercentile}) {
    Volume v;
    v.nx = 4;
    v.ny = 1;
    v.nz = 1;
    v.voxels = {-big, 0.0f, big, -big};
    NormalizationOptions o;
    o.method = method;
    o.percentile_lo = 0;
    o.percentile_hi = 100;
    normalize(v, o);
    EXPECT_EQ(v.voxels[0], 0.0f);
    EXPECT_EQ(v.voxels[1], 0.5f);
    EXPECT_EQ(v.voxels[2], 1.0f);
    EXPECT_EQ(v.voxels[3], 0.0f);
  }
}

TEST(VolumeNormalize, RejectsBadPercentiles) {
  NormalizationOptions o;
  o.percentile_lo = 50;
  o.percentile_hi = 40;
  EXPECT_THROW(o.validate(), InputError);
}

TEST(VolumeStats, CountsForegroundAsDataReadmeDefines) {
  Volume v;
  v.nx = 10;
  v.ny = 1;
  v.nz = 1;
  v.voxels = {0, 0, 0, 0, 0, 0, 10, 20, 30, 100};
  const VolumeStats s = compute_stats(v, 0.2);
  EXPECT_EQ(s.min, 0);
  EXPECT_EQ(s.max, 100);
  EXPECT_DOUBLE_EQ(s.nonzero_fraction, 0.4);
  EXPECT_DOUBLE_EQ(s.foreground_fraction, 0.2);  // 30 and 100 are > 20
  EXPECT_DOUBLE_EQ(s.mean, 16.0);
  EXPECT_DOUBLE_EQ(s.p50, 0.0);
}

TEST(VolumeSpacing, DescribeGroupsAxesBySource) {
  VoxelSpacing s;
  s.um = {0.3296, 0.3296, 0.9988};
  s.source = {SpacingSource::kImageJResolution, SpacingSource::kImageJResolution, SpacingSource::kImageJSpacing};
  const std::string d = s.describe();
  EXPECT_NE(d.find("x, y: ImageJ X/YResolution; z: ImageJ spacing="), std::string::npos) << d;
}

}  // namespace
}  // namespace hisnegs::io
