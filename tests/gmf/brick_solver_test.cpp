// SPDX-License-Identifier: Apache-2.0
// gmf/brick_solver: the partition (every Gaussian in one brick, crowded bricks
// halved), the colouring (bricks of one colour never share a sample block: a
// property over random mixtures) and the sweep (lowers the loss; the same result,
// bit for bit, for one and two threads).
#include "gmf/brick_solver.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <random>
#include <set>

#include "gmf/fit.hpp"
#include "gmf/objective.hpp"
#include "tests/gmf/gmf_test_scenes.hpp"

namespace hisnegs::gmf {
namespace {

std::vector<ParamsD> params_of(const GaussianMixture& m) {
  std::vector<ParamsD> p(m.size());
  for (std::size_t k = 0; k < m.size(); ++k) {
    const auto a = to_array(m[k]);
    std::copy(a.begin(), a.end(), p[k].begin());
  }
  return p;
}

// A mixture of `n` Gaussians at random places of the scene's volume (crowded:
// many overlap), σ 0.7-3 voxels.
GaussianMixture random_mixture(const Scene& scene, int n, std::mt19937_64& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  GaussianMixture m;
  const double voxel = scene.frame.voxel_size().x();
  for (int i = 0; i < n; ++i) {
    GaussianParams g;
    const Eigen::Vector3d p = scene.frame.world_from_index(Eigen::Vector3d(48 * u(rng), 48 * u(rng), 24 * u(rng)));
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(p[a]);
    for (int a = 0; a < 3; ++a) g.log_scale[a] = static_cast<float>(std::log((0.7 + 2.3 * u(rng)) * voxel));
    g.intensity_logit = static_cast<float>(u(rng) - 0.5);
    m.push_back(g);
  }
  return m;
}

// A scene's samples and its truth with means moved by ~0.3 voxel and logits by
// ~0.4, indexed with the padding of a fit round; parameters unbounded.
struct PerturbedScene {
  Scene scene = make_scene(5);
  SampleSet samples = extract_samples(grid_of(scene, 0.05), 1.0, 2);
  GaussianMixture start = perturbed(scene);
  BlockIndex index = build_block_index(start, samples, scene.frame, 16.0, 1.25, scene.frame.voxel_size().x());
  std::vector<ParamsD> p0 = params_of(start);
  std::vector<double> lower = std::vector<double>(p0.size() * kGaussianParamCount, -1e30);
  std::vector<double> upper = std::vector<double>(p0.size() * kGaussianParamCount, 1e30);

  static GaussianMixture perturbed(const Scene& scene) {
    std::mt19937_64 rng(8);
    std::normal_distribution<double> n(0, 1);
    GaussianMixture m = scene.truth;
    const double voxel = scene.frame.voxel_size().x();
    for (auto& g : m) {
      for (int a = 0; a < 3; ++a) g.mean[a] += static_cast<float>(0.3 * voxel * n(rng));
      g.intensity_logit += static_cast<float>(0.4 * n(rng));
    }
    return m;
  }
};

TEST(BrickSolver, ColoursNeverShareASampleBlockAndEveryGaussianHasOneBrick) {
  const Scene scene = make_scene(3);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  std::mt19937_64 rng(21);
  for (int trial = 0; trial < 12; ++trial) {
    const GaussianMixture m = random_mixture(scene, 50 + 40 * trial, rng);
    const BlockIndex index = build_block_index(m, samples, scene.frame, 16.0);
    const int brick_voxels = 4 << (trial % 3), max_gaussians = 2 + trial;
    const BrickPartition p = partition_into_bricks(params_of(m), index, scene.frame, brick_voxels, max_gaussians);
    // Every Gaussian in exactly the brick brick_of names.
    std::vector<int> seen(m.size(), 0);
    for (std::size_t b = 0; b < p.gaussians.size(); ++b) {
      for (std::uint32_t g : p.gaussians[b]) {
        ++seen[g];
        EXPECT_EQ(p.brick_of[g], b);
      }
    }
    for (int s : seen) EXPECT_EQ(s, 1);
    // Every brick in exactly one colour; within a colour, no sample block is reached
    // by Gaussians of two different bricks.
    std::vector<int> coloured(p.gaussians.size(), 0);
    for (const auto& colour : p.colours) {
      std::vector<std::int64_t> owner(samples.blocks(), -1);
      for (std::uint32_t b : colour) {
        ++coloured[b];
        for (std::uint32_t g : p.gaussians[b]) {
          for (std::size_t block = 0; block < samples.blocks(); ++block) {
            const auto ids = index.of(block);
            if (std::find(ids.begin(), ids.end(), g) == ids.end()) continue;
            EXPECT_TRUE(owner[block] == -1 || owner[block] == b)
                << "trial " << trial << ": bricks " << owner[block] << " and " << b << " of one colour share block "
                << block;
            owner[block] = b;
          }
        }
      }
    }
    for (int c : coloured) EXPECT_EQ(c, 1);
  }
}

// A sweep lowers the loss of a perturbed truth and gives the same parameters, bit
// for bit, on one thread and on two.
TEST(BrickSolver, SweepLowersTheLossAndIsTheSameForAnyThreadCount) {
  const PerturbedScene t;
  const auto& [scene, samples, start, index, p0, lower, upper] = t;
  for (const Aggregation aggregation : {Aggregation::kSum, Aggregation::kSoftmax}) {
    const MixtureModel model{.aggregation = aggregation, .beta = 32.0, .cutoff = 16.0};
    const BrickPartition partition = partition_into_bricks(p0, index, scene.frame, 16, 4);
    ASSERT_GT(partition.colours.size(), 1u);
    BrickSweepOptions so;
    so.model = model;
    so.iterations = 5;
    std::vector<std::vector<ParamsD>> results;
    for (const int threads : {1, 2}) {
      const tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
      std::vector<ParamsD> p = p0;
      const BrickSweepStats stats = sweep_bricks(samples, index, partition, p, lower, upper, so);
      EXPECT_EQ(stats.bricks_skipped, 0);
      EXPECT_GT(stats.iterations, 0);
      results.push_back(p);
    }
    for (std::size_t k = 0; k < p0.size(); ++k) EXPECT_EQ(results[0][k], results[1][k]) << "gaussian " << k;
    const FitObjective objective(samples, index, p0.size(), model);
    const double before = objective.evaluate(p0[0].data(), nullptr);
    const double after = objective.evaluate(results[0][0].data(), nullptr);
    EXPECT_LT(after, 0.5 * before) << (aggregation == Aggregation::kSum ? "sum" : "softmax");
  }
}

// The brick problem as the sweep builds it by default (each Gaussian only in the
// blocks it can reach, blocks grouped into residual blocks of at most 8 Gaussians,
// sparse normal equations) reaches the loss of the plain one (every indexed
// Gaussian in every block of the brick, one dense residual block).
TEST(BrickSolver, ReachLimitedChunkedBricksMatchThePlainDenseProblem) {
  const PerturbedScene t;
  const auto& [scene, samples, start, index, p0, lower, upper] = t;
  for (const Aggregation aggregation : {Aggregation::kSum, Aggregation::kSoftmax}) {
    const MixtureModel model{.aggregation = aggregation, .beta = 32.0, .cutoff = 16.0};
    const BrickPartition partition = partition_into_bricks(p0, index, scene.frame, 16, 12);
    BrickSweepOptions plain;
    plain.model = model;
    plain.iterations = 20;
    plain.reach_margin = 1e30;
    plain.chunk_gaussians = 1 << 30;
    plain.sparse = false;
    BrickSweepOptions fast = plain;
    fast.reach_margin = BrickSweepOptions{}.reach_margin;
    fast.chunk_gaussians = BrickSweepOptions{}.chunk_gaussians;
    fast.sparse = BrickSweepOptions{}.sparse;
    std::vector<ParamsD> p_plain = p0, p_fast = p0;
    sweep_bricks(samples, index, partition, p_plain, lower, upper, plain);
    sweep_bricks(samples, index, partition, p_fast, lower, upper, fast);
    const FitObjective objective(samples, index, p0.size(), model);
    const double before = objective.evaluate(p0[0].data(), nullptr);
    const double loss_plain = objective.evaluate(p_plain[0].data(), nullptr);
    const double loss_fast = objective.evaluate(p_fast[0].data(), nullptr);
    const char* name = aggregation == Aggregation::kSum ? "sum" : "softmax";
    EXPECT_LT(loss_plain, 0.5 * before) << name;
    EXPECT_NEAR(loss_fast, loss_plain, 0.02 * (before - loss_plain)) << name << ": before " << before;
  }
}

}  // namespace
}  // namespace hisnegs::gmf
