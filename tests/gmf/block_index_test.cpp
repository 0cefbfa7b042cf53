// SPDX-License-Identifier: Apache-2.0
// gmf/block_index: which Gaussians reach which sample block, against a brute
// force over every voxel centre of every block (plain and padded supports), the
// ascending CSR lists, and the loss of the blocks no Gaussian reaches.
#include "gmf/block_index.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/samples.hpp"
#include "io/sparse_grid.hpp"

namespace hisnegs::gmf {
namespace {

TEST(BlockIndex, ListsExactlyTheGaussiansWhoseSupportReachesABlock) {
  // A 32^3 volume in the unit box; blocks at origins (0,0,0) and (24,24,24).
  const io::WorldFrame frame(32, 32, 32, Eigen::Vector3d::Ones());
  SampleSet s;
  s.block_begin = {0, 1, 2};
  s.block_origin = {{0, 0, 0}, {24, 24, 24}};
  for (int b = 0; b < 2; ++b) {
    const Eigen::Vector3d p = frame.world_from_index(Eigen::Vector3d(b * 24 + 3, b * 24 + 3, b * 24 + 3));
    s.x.push_back(p.x());
    s.y.push_back(p.y());
    s.z.push_back(p.z());
    s.value.push_back(1);
    s.weight.push_back(1);
  }
  GaussianMixture mix;
  auto add = [&](const Eigen::Vector3d& ijk, double sigma_voxels) {
    GaussianParams g;
    const Eigen::Vector3d p = frame.world_from_index(ijk);
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(p[a]);
    for (int a = 0; a < 3; ++a) g.log_scale[a] = static_cast<float>(std::log(sigma_voxels * frame.voxel_size()[a]));
    mix.push_back(g);
  };
  add({3, 3, 3}, 1.0);     // inside block 0
  add({12, 3, 3}, 1.0);    // 4σ = 4 voxels: reaches x = 8.. -> not block 0 (centres 0..7)
  add({10, 3, 3}, 1.0);    // reaches x = 6: touches block 0
  add({16, 16, 16}, 3.0);  // 4σ = 12 voxels: reaches 4..28 -> both blocks
  add({28, 28, 28}, 0.5);  // block 1 only
  const BlockIndex index = build_block_index(mix, s, frame, 16.0);
  const auto b0 = index.of(0), b1 = index.of(1);
  EXPECT_EQ(std::vector<std::uint32_t>(b0.begin(), b0.end()), (std::vector<std::uint32_t>{0, 2, 3}));
  EXPECT_EQ(std::vector<std::uint32_t>(b1.begin(), b1.end()), (std::vector<std::uint32_t>{3, 4}));
}

// A 40 × 24 × 16 stack (voxels of 0.05 world units) with scattered foreground
// and 10% background samples (weight sqrt(10)), in blocks of 4 voxels: blocks
// of both parts, some sharing an origin.
struct Blocks {
  io::WorldFrame frame{40, 24, 16, Eigen::Vector3d(1.0, 0.6, 0.4)};
  io::SparseGrid grid;
  SampleSet samples;
  GaussianMixture mixture;
};

Blocks make_blocks(std::uint64_t seed, int gaussians) {
  Blocks s;
  io::Volume v;
  v.nx = 40;
  v.ny = 24;
  v.nz = 16;
  v.source = "blocks";
  v.normalization.method = io::NormalizationMethod::kMinMax;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  v.voxels.resize(v.size());
  // Dim (below threshold) but non-zero elsewhere, so background samples carry a value.
  for (float& x : v.voxels) x = u(rng) < 0.01f ? 0.5f + 0.5f * u(rng) : 0.05f * u(rng);
  io::SparseGridOptions o;
  o.threshold = 0.3;
  o.band_voxels = 1;
  o.background_fraction = 0.1;
  o.seed = seed;
  s.grid = io::build_sparse_grid(v, s.frame.aspect(), o);
  s.samples = extract_samples(s.grid, 1.0, 4);
  // σ 0.6-2 voxels: every support box is wider than a voxel along each axis, so
  // "the box overlaps the block's span of voxel centres" and "the box holds one
  // of the block's voxel centres" are the same.
  std::uniform_real_distribution<double> p(-1, 1), sigma(0.03, 0.1);
  std::normal_distribution<double> n(0, 1);
  for (int k = 0; k < gaussians; ++k) {
    GaussianParams g;
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(1.1 * s.frame.aspect()[a] * p(rng));
    for (int a = 0; a < 3; ++a) g.log_scale[a] = static_cast<float>(std::log(sigma(rng)));
    for (int a = 0; a < 4; ++a) g.rotation[a] = static_cast<float>(n(rng));
    s.mixture.push_back(g);
  }
  return s;
}

// Gaussians whose support box (sqrt(δ Σ_ii) · scale_pad + pad_world about μ, from
// the Eigen covariance) holds a voxel centre of block b's block of `block`³ voxels.
std::vector<std::uint32_t> brute_force(const Blocks& s, std::size_t b, double cutoff, double scale_pad,
                                       double pad_world) {
  std::vector<std::uint32_t> ids;
  const auto& o = s.samples.block_origin[b];
  const int n = s.samples.block;
  for (std::size_t k = 0; k < s.mixture.size(); ++k) {
    const GaussianParams& g = s.mixture[k];
    const Eigen::Matrix3d cov = covariance(g);
    bool reached = false;
    for (int i = 0; i < n && !reached; ++i)
      for (int j = 0; j < n && !reached; ++j)
        for (int l = 0; l < n && !reached; ++l) {
          const Eigen::Vector3d c = s.frame.world_from_index(Eigen::Vector3d(o[0] + i, o[1] + j, o[2] + l));
          bool in = true;
          for (int a = 0; a < 3; ++a) {
            const double half = std::sqrt(cutoff * cov(a, a)) * scale_pad + pad_world;
            in = in && std::abs(c[a] - g.mean[a]) <= half;
          }
          reached = in;
        }
    if (reached) ids.push_back(static_cast<std::uint32_t>(k));
  }
  return ids;
}

void expect_matches_brute_force(const Blocks& s, double cutoff, double scale_pad, double pad_world) {
  const BlockIndex index = build_block_index(s.mixture, s.samples, s.frame, cutoff, scale_pad, pad_world);
  ASSERT_EQ(index.begin.size(), s.samples.blocks() + 1);
  EXPECT_EQ(index.begin.back(), index.gaussians.size());
  std::size_t empty = 0, shared = 0;
  for (std::size_t b = 0; b < s.samples.blocks(); ++b) {
    const auto listed = index.of(b);
    const std::vector<std::uint32_t> expected = brute_force(s, b, cutoff, scale_pad, pad_world);
    EXPECT_EQ(std::vector<std::uint32_t>(listed.begin(), listed.end()), expected) << "block " << b;
    empty += expected.empty() ? 1 : 0;
    shared += expected.size() >= 2 ? 1 : 0;
  }
  // Both kinds occur, so the comparison means something.
  EXPECT_GT(empty, 10u);
  EXPECT_GT(shared, 10u);
}

TEST(BlockIndex, ListsTheBlocksWhoseVoxelCentresTheSupportBoxHolds) {
  const Blocks s = make_blocks(71, 40);
  ASSERT_GT(s.samples.background, 0);
  ASSERT_GT(s.samples.blocks(), 200u);
  expect_matches_brute_force(s, 16.0, 1.0, 0.0);
  expect_matches_brute_force(s, 9.0, 1.0, 0.0);
}

// The box grown to half · scale_pad + pad_world (pad of 1.5 voxels).
TEST(BlockIndex, PaddedSupportsListTheBlocksThePaddedBoxHolds) {
  const Blocks s = make_blocks(73, 12);
  expect_matches_brute_force(s, 16.0, 1.5, 0.0);
  expect_matches_brute_force(s, 9.0, 1.2, 1.5 * s.frame.voxel_size().x());
  // Padding only adds blocks.
  const BlockIndex plain = build_block_index(s.mixture, s.samples, s.frame, 16.0);
  const BlockIndex padded = build_block_index(s.mixture, s.samples, s.frame, 16.0, 1.5, 0.1);
  EXPECT_GT(padded.gaussians.size(), plain.gaussians.size());
}

// Each block's list is strictly ascending (no duplicates), though pairs are
// produced in parallel over Gaussians.
TEST(BlockIndex, IdsAreStrictlyAscending) {
  const Blocks s = make_blocks(79, 200);
  const BlockIndex index = build_block_index(s.mixture, s.samples, s.frame, 16.0, 1.3, 0.05);
  std::size_t longest = 0;
  for (std::size_t b = 0; b < s.samples.blocks(); ++b) {
    const auto ids = index.of(b);
    longest = std::max(longest, ids.size());
    for (std::size_t i = 1; i < ids.size(); ++i) EXPECT_LT(ids[i - 1], ids[i]) << "block " << b;
  }
  EXPECT_GE(longest, 5u);
}

// unreached_loss = ½ Σ (w V)² over the samples of the blocks whose list is empty,
// and 0 when every block is reached.
TEST(BlockIndex, UnreachedLossSumsTheBlocksNoGaussianReaches) {
  const Blocks s = make_blocks(83, 8);
  const BlockIndex index = build_block_index(s.mixture, s.samples, s.frame, 16.0);
  double expected = 0, total = 0;
  for (std::size_t b = 0; b < s.samples.blocks(); ++b) {
    for (std::uint32_t j = s.samples.block_begin[b]; j < s.samples.block_begin[b + 1]; ++j) {
      const double wv = s.samples.weight[j] * s.samples.value[j];
      total += 0.5 * wv * wv;
      if (index.of(b).empty()) expected += 0.5 * wv * wv;
    }
  }
  ASSERT_GT(expected, 0.0);
  ASSERT_LT(expected, total);  // some blocks are reached
  EXPECT_NEAR(unreached_loss(s.samples, index), expected, 1e-12 * expected);
  const BlockIndex everywhere = build_block_index(s.mixture, s.samples, s.frame, 1e9);
  EXPECT_EQ(unreached_loss(s.samples, everywhere), 0.0);
}

}  // namespace
}  // namespace hisnegs::gmf
