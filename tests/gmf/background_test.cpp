// SPDX-License-Identifier: Apache-2.0
// gmf::BackgroundModel: E[max of n] against a Monte-Carlo draw from the same
// distribution, the estimate's atoms on a stack of known noise (the neuron and its
// halo left out), a zero background as none, and the text form round trip.
#include "gmf/core/background.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "io/error.hpp"

namespace hisnegs::gmf {
namespace {

// A stack of Poisson(lambda) counts / 255 (op1's noisy recipe) with a bright rod
// through it whose dim halo (0.05) reaches 2 voxels out.
io::Volume noisy_stack(double lambda, std::uint64_t seed) {
  io::Volume v;
  v.nx = 48, v.ny = 40, v.nz = 24;
  v.voxels.assign(v.size(), 0.0f);
  std::mt19937_64 rng(seed);
  std::poisson_distribution<int> counts(lambda);
  for (float& x : v.voxels) x = static_cast<float>(counts(rng)) / 255.0f;
  for (int z = 8; z < 16; ++z)
    for (int y = 18; y < 22; ++y)
      for (int x = 0; x < v.nx; ++x) v.at(x, y, z) = 0.8f;
  for (int z = 6; z < 18; ++z)
    for (int y = 16; y < 24; ++y)
      for (int x = 0; x < v.nx; ++x) {
        if (v.at(x, y, z) < 0.5f) v.at(x, y, z) = 0.05f;
      }
  v.source = "noisy.tif";
  return v;
}

TEST(Background, ExpectedMaxMatchesAMonteCarloDraw) {
  BackgroundModel m;
  m.values = {0.0, 1 / 255.0, 2 / 255.0, 3 / 255.0, 5 / 255.0};
  m.cdf = {0.55, 0.88, 0.97, 0.995, 1.0};
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (const int n : {1, 7, 60, 400}) {
    double sum = 0;
    constexpr int kTrials = 20000;
    for (int t = 0; t < kTrials; ++t) {
      double top = 0;
      for (int i = 0; i < n; ++i) top = std::max(top, m.quantile(u(rng)));
      sum += top;
    }
    const double mc = sum / kTrials;
    // The Monte-Carlo mean's standard error is below 0.5 % of these values.
    EXPECT_NEAR(m.expected_max(n), mc, 0.01 * mc + 1e-6) << "n = " << n;
  }
  EXPECT_DOUBLE_EQ(m.expected_max(1), m.mean());
  EXPECT_LE(m.expected_max(1e6), 5 / 255.0 + 1e-12);  // never past the largest atom
  EXPECT_GT(m.expected_max(1e6), 4.99 / 255.0);
}

TEST(Background, EstimateLeavesTheNeuronAndItsHaloOut) {
  const double lambda = 0.6;
  const io::Volume v = noisy_stack(lambda, 11);
  const BackgroundModel m = estimate_background(v);
  ASSERT_FALSE(m.none());
  EXPECT_EQ(m.values.front(), 0.0);
  // Poisson(0.6): P(0) = e^-0.6 = 0.549, mean 0.6 / 255; the rod's 0.05 halo is not an atom.
  EXPECT_NEAR(m.cdf.front(), std::exp(-lambda), 0.01);
  EXPECT_NEAR(m.mean(), lambda / 255.0, 0.03 * lambda / 255.0);
  for (const double value : m.values) EXPECT_LT(value, 0.04) << "halo or rod voxels counted as background";
  EXPECT_GT(m.voxels, static_cast<std::int64_t>(v.size() / 2));
  // Without the guard the halo comes in.
  BackgroundOptions no_guard;
  no_guard.guard_voxels = 0;
  EXPECT_DOUBLE_EQ(estimate_background(v, no_guard).values.back(), 0.05f);
}

// Bricks: counting each core of a tiling inside its region (core + a halo as wide as
// the guard) and merging gives the whole stack's estimate exactly.
TEST(Background, CountsOfBricksWithAGuardHaloMergeIntoTheWholeEstimate) {
  const io::Volume v = noisy_stack(0.6, 4);
  const BackgroundOptions options;
  const int g = options.guard_voxels;
  BackgroundCounts merged;
  for (int z0 = 0; z0 < v.nz; z0 += 10) {
    for (int x0 = 0; x0 < v.nx; x0 += 20) {
      const io::VoxelBox core{{x0, 0, z0}, {std::min(v.nx, x0 + 20), v.ny, std::min(v.nz, z0 + 10)}};
      const io::VoxelBox region{{std::max(0, x0 - g), 0, std::max(0, z0 - g)},
                            {std::min(v.nx, core.hi[0] + g), v.ny, std::min(v.nz, core.hi[2] + g)}};
      io::Volume r;
      r.nx = region.hi[0] - region.lo[0], r.ny = v.ny, r.nz = region.hi[2] - region.lo[2];
      for (int z = region.lo[2]; z < region.hi[2]; ++z)
        for (int y = 0; y < v.ny; ++y)
          for (int x = region.lo[0]; x < region.hi[0]; ++x) r.voxels.push_back(v.at(x, y, z));
      const io::VoxelBox local{{core.lo[0] - region.lo[0], 0, core.lo[2] - region.lo[2]},
                           {core.hi[0] - region.lo[0], v.ny, core.hi[2] - region.lo[2]}};
      merged.merge(count_background(r, options, local));
    }
  }
  EXPECT_EQ(background_from_counts(merged, options, "bricks"), estimate_background(v, options));
}

TEST(BackgroundRegions, SplitTheStackIntoEqualPartsThatTileIt) {
  const BackgroundRegions r = BackgroundRegions::of({100, 120, 40}, 32);
  EXPECT_EQ(r.cells, (std::array<int, 3>{4, 4, 2}));
  EXPECT_EQ(BackgroundRegions::of({100, 120, 40}, 0).count(), 1);
  EXPECT_EQ(BackgroundRegions::of({5000, 20, 3}, 16).cells, (std::array<int, 3>{8, 2, 1}));  // at most 8 a side
  std::size_t voxels = 0;
  for (int i = 0; i < r.count(); ++i) {
    const io::VoxelBox b = r.box(i);
    voxels += b.voxels();
    for (int a = 0; a < 3; ++a) {
      const int k = a == 0 ? i % 4 : a == 1 ? (i / 4) % 4 : i / 16;
      EXPECT_EQ(r.cell_of(a, b.lo[a]), k);
      EXPECT_EQ(r.cell_of(a, b.hi[a] - 1), k);
    }
  }
  EXPECT_EQ(voxels, 100u * 120u * 40u);
}

// Three regions along x: Poisson noise, a subtracted (zero) background, and one the
// neuron fills (no background voxel: it takes the whole stack's distribution).
io::Volume three_part_stack() {
  io::Volume v = noisy_stack(0.6, 7);
  io::Volume out;
  out.nx = 96, out.ny = v.ny, out.nz = v.nz;
  out.voxels.assign(out.size(), 0.0f);
  for (int z = 0; z < v.nz; ++z)
    for (int y = 0; y < v.ny; ++y)
      for (int x = 0; x < 32; ++x) {
        out.at(x, y, z) = v.at(x, y, z);
        out.at(64 + x, y, z) = 0.9f;
      }
  out.source = "three.tif";
  return out;
}

TEST(BackgroundField, EachRegionHasItsOwnDistribution) {
  const io::Volume v = three_part_stack();
  BackgroundOptions options;
  options.region_voxels = 32;
  const BackgroundField field = estimate_background_field(v, options);
  ASSERT_TRUE(field.regional());
  ASSERT_EQ(field.regions.cells, (std::array<int, 3>{3, 2, 1}));
  EXPECT_FALSE(field.merged.none());
  for (int y = 0; y < 2; ++y) {
    EXPECT_FALSE(field.at(3 * y).none()) << "the noisy part";
    EXPECT_NE(field.at(3 * y), field.merged);
    EXPECT_GT(field.at(3 * y).mean(), field.merged.mean()) << "the noise alone, not diluted by the zeros";
    EXPECT_TRUE(field.at(3 * y + 1).none()) << "the subtracted part draws no floor";
    EXPECT_EQ(field.at(3 * y + 2), field.merged) << "the filled part has no background of its own";
  }
  // The summary the fit's line and `info` print: two subtracted, two on the merged
  // model, the 99th percentiles of the others (the noisy parts and the merged ones).
  const BackgroundField::Summary summary = field.summary();
  EXPECT_EQ(summary.subtracted, 2);
  EXPECT_EQ(summary.merged, 2);
  const double p0 = field.at(0).quantile(0.99), p3 = field.at(3).quantile(0.99), pm = field.merged.quantile(0.99);
  EXPECT_EQ(summary.p99_lo, std::min({p0, p3, pm}));
  EXPECT_EQ(summary.p99_hi, std::max({p0, p3, pm}));
  options.region_voxels = 0;
  const BackgroundField one = estimate_background_field(v, options);
  EXPECT_FALSE(one.regional());
  EXPECT_EQ(one.merged, field.merged);
  EXPECT_EQ(one.merged, estimate_background(v, options));
}

TEST(BackgroundField, CountsOfBricksByRegionMergeIntoTheWholeField) {
  const io::Volume v = three_part_stack();
  BackgroundOptions options;
  options.region_voxels = 32;
  const BackgroundRegions regions = BackgroundRegions::of({v.nx, v.ny, v.nz}, options.region_voxels);
  const int g = options.guard_voxels;
  std::vector<BackgroundCounts> merged(static_cast<std::size_t>(regions.count()));
  for (int x0 = 0; x0 < v.nx; x0 += 40) {  // bricks that do not line up with the regions
    const int x1 = std::min(v.nx, x0 + 40), lo = std::max(0, x0 - g), hi = std::min(v.nx, x1 + g);
    io::Volume r;
    r.nx = hi - lo, r.ny = v.ny, r.nz = v.nz;
    for (int z = 0; z < v.nz; ++z)
      for (int y = 0; y < v.ny; ++y)
        for (int x = lo; x < hi; ++x) r.voxels.push_back(v.at(x, y, z));
    const io::VoxelBox core{{x0 - lo, 0, 0}, {x1 - lo, v.ny, v.nz}};
    const std::vector<BackgroundCounts> part = count_background_regions(r, options, core, regions, {lo, 0, 0});
    for (std::size_t i = 0; i < merged.size(); ++i) merged[i].merge(part[i]);
  }
  const BackgroundField bricked = background_field(merged, regions, options, "bricks");
  const BackgroundField whole = estimate_background_field(v, options);
  EXPECT_EQ(bricked.merged, whole.merged);
  EXPECT_EQ(bricked.models, whole.models);
}

TEST(Background, AZeroBackgroundIsNone) {
  io::Volume v = noisy_stack(0.0, 1);
  const BackgroundModel m = estimate_background(v);
  EXPECT_TRUE(m.none());
  EXPECT_EQ(m.expected_max(500), 0.0);
  EXPECT_TRUE(BackgroundModel{}.none());
  // Every voxel foreground: an error naming the stack.
  std::fill(v.voxels.begin(), v.voxels.end(), 0.9f);
  EXPECT_THROW((void)estimate_background(v), io::InputError);
}

// A background-subtracted stack (the shared ones: 99.9 % to 100 % of the background
// exactly 0) keeps a few remnants of structure, not a noise floor: none.
TEST(Background, ASubtractedBackgroundIsNone) {
  io::Volume v = noisy_stack(0.0, 2);
  for (std::size_t i = 0; i < v.voxels.size(); i += 997) {
    if (v.voxels[i] == 0.0f) v.voxels[i] = 0.03f;  // ~0.1 % speckles
  }
  EXPECT_TRUE(estimate_background(v).none());
  BackgroundOptions keep;
  keep.subtracted_zero_fraction = 1.0;  // only an all-zero background is none
  const BackgroundModel m = estimate_background(v, keep);
  EXPECT_FALSE(m.none());
  EXPECT_NEAR(m.cdf.front(), 0.999, 0.0005);
  keep.subtracted_zero_fraction = 0.0;
  EXPECT_THROW(keep.validate(), io::InputError);
}

TEST(Background, ManyDistinctValuesAreBinnedKeepingTheMean) {
  io::Volume v = noisy_stack(0.6, 5);
  std::mt19937_64 rng(8);
  std::exponential_distribution<double> noise(300.0);  // continuous: every value distinct
  for (float& x : v.voxels) {
    if (x < 0.04f) x = static_cast<float>(std::min(noise(rng), 0.15));
  }
  BackgroundOptions options;
  options.max_atoms = 64;
  const BackgroundModel m = estimate_background(v, options);
  EXPECT_LE(m.values.size(), 64u);
  double sum = 0;
  std::int64_t count = 0;
  for (int z = 0; z < v.nz; ++z)
    for (int y = 0; y < v.ny; ++y)
      for (int x = 0; x < v.nx; ++x) {
        // The rod (z 8-15, y 18-21, above the foreground level) and 3 voxels around it.
        const bool near_rod = z >= 8 - 3 && z < 16 + 3 && y >= 18 - 3 && y < 22 + 3;
        if (!near_rod) {
          sum += v.at(x, y, z);
          ++count;
        }
      }
  EXPECT_EQ(m.voxels, count);
  EXPECT_NEAR(m.mean(), sum / static_cast<double>(count), 1e-6);
}

TEST(Background, TextRoundTripsAndBadTextIsRefused) {
  BackgroundModel m;
  m.values = {0.0, 0.1 / 3, 0.05};
  m.cdf = {0.5, 0.9, 1.0};
  m.samples_per_voxel = 0.7312;
  EXPECT_EQ(BackgroundModel::parse(m.text(), "m.ply"), m);
  for (const char* bad :
       {"", "x 2", "1 2 0 0.5", "1 1 0 0.5", "1 2 0.1 0.5 0.05 1", "0 1 0 1", "1 1 0 1 extra", "1 1 nan 1"}) {
    EXPECT_THROW((void)BackgroundModel::parse(bad, "m.ply"), io::InputError) << bad;
  }
  try {
    (void)BackgroundModel::parse("1 1 0 0.5", "m.ply");
  } catch (const io::InputError& e) {
    EXPECT_EQ(std::string(e.what()), "m.ply: background: the last probability is 0.5, not 1");
  }
}

}  // namespace
}  // namespace hisnegs::gmf
