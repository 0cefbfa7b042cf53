// SPDX-License-Identifier: Apache-2.0
// Tests that the real neuron stacks in ../shared/data read exactly as their README states (shape, dtype,
// range, spacing and its source). Skipped when the folder is absent; synthetic fixtures are tiff_stack_test's.
#include <gtest/gtest.h>

#include <algorithm>
#include <string>

#include "io/tiff_stack.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {

struct Expected {
  const char* name;
  int nz, ny, nx;
  float min, max;
  double sx, sy, sz;
  SpacingSource source_xy, source_z;
};

void check(const Expected& e) {
  const auto path = hisnegs::testing::shared_data(e.name);
  if (!path) GTEST_SKIP() << "../shared/data/" << e.name << " not present";
  const TiffStackInfo info = inspect_tiff_stack(*path);
  EXPECT_EQ(info.nx, e.nx);
  EXPECT_EQ(info.ny, e.ny);
  EXPECT_EQ(info.nz, e.nz);
  EXPECT_EQ(info.channels, 1);
  EXPECT_EQ(info.type, SampleType::kUint8);

  const Volume v = read_tiff_stack(*path);
  EXPECT_EQ(v.nx, e.nx);
  EXPECT_EQ(v.ny, e.ny);
  EXPECT_EQ(v.nz, e.nz);
  EXPECT_EQ(v.stored_as, SampleType::kUint8);
  ASSERT_EQ(v.voxels.size(), v.size());
  const auto [lo, hi] = std::minmax_element(v.voxels.begin(), v.voxels.end());
  EXPECT_EQ(*lo, e.min);
  EXPECT_EQ(*hi, e.max);
  // The README gives 4 decimals; X/YResolution is 3.033534 px/µm (0.32965 µm).
  EXPECT_NEAR(v.spacing.um[0], e.sx, 1e-4);
  EXPECT_NEAR(v.spacing.um[1], e.sy, 1e-4);
  EXPECT_NEAR(v.spacing.um[2], e.sz, 1e-9);
  EXPECT_EQ(v.spacing.source[0], e.source_xy);
  EXPECT_EQ(v.spacing.source[1], e.source_xy);
  EXPECT_EQ(v.spacing.source[2], e.source_z);
  EXPECT_EQ(info.spacing.um, v.spacing.um);
}

TEST(SharedData, Op1Neuron) {
  check({"op1_neuron.tif", 60, 512, 512, 0, 254, 0.3296, 0.3296, 0.9988, SpacingSource::kImageJResolution,
         SpacingSource::kImageJSpacing});
}

TEST(SharedData, Op2Neuron) {
  check({"op2_neuron.tif", 88, 512, 512, 0, 254, 0.3296, 0.3296, 0.9988, SpacingSource::kImageJResolution,
         SpacingSource::kImageJSpacing});
}

// The raw stack: as acquired, its background not zeroed (README: 47.8 % of the voxels non-zero).
TEST(SharedData, Op3Raw) {
  check({"op3_raw.tif", 62, 512, 512, 0, 254, 0.3296, 0.3296, 0.9988, SpacingSource::kImageJResolution,
         SpacingSource::kImageJSpacing});
  const auto path = hisnegs::testing::shared_data("op3_raw.tif");
  if (!path) return;
  const Volume v = read_tiff_stack(*path);
  const auto nonzero = std::count_if(v.voxels.begin(), v.voxels.end(), [](float x) { return x != 0.0f; });
  EXPECT_NEAR(static_cast<double>(nonzero) / static_cast<double>(v.size()), 0.478, 0.005);
}

TEST(SharedData, RivuletTestNeuron) {
  check({"rivulet_test_neuron.tif", 119, 415, 409, 0, 255, 1, 1, 1, SpacingSource::kDefault, SpacingSource::kDefault});
}

}  // namespace
}  // namespace hisnegs::io
