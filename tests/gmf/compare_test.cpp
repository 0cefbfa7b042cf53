// SPDX-License-Identifier: Apache-2.0
// compare_optimizers on a tiny scene: Adam defines the target, every run starts
// from the same mixture, times to target are read from the runs' own logs.
#include "gmf/compare.hpp"

#include <gtest/gtest.h>

#include "gmf/init.hpp"
#include "gmf/rasterize.hpp"
#include "io/error.hpp"
#include "io/sparse_grid.hpp"

namespace hisnegs::gmf {
namespace {

struct CompareScene {
  io::Volume volume;
  io::WorldFrame frame;
  GaussianMixture truth;
};

// Six Gaussians on a line in a 32x24x16 volume.
CompareScene make_compare_scene() {
  CompareScene s;
  s.volume.nx = 32;
  s.volume.ny = 24;
  s.volume.nz = 16;
  s.frame = io::WorldFrame(32, 24, 16, Eigen::Vector3d(1.0, 1.0, 1.0));
  for (int k = 0; k < 6; ++k) {
    GaussianParams g;
    const Eigen::Vector3d p = s.frame.world_from_index(Eigen::Vector3d(5 + 4.4 * k, 8 + k, 6 + k % 3));
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(p[a]);
    for (int a = 0; a < 3; ++a) g.log_scale[a] = std::log(static_cast<float>(1.5 * s.frame.voxel_size().x()));
    g.intensity_logit = 0.5f;
    s.truth.push_back(g);
  }
  s.volume.voxels = rasterize_mixture(s.truth, s.frame, {.cutoff = 1e9});
  return s;
}

TEST(GmfCompare, AdamDefinesTheTargetAndRunsFirst) {
  const CompareScene scene = make_compare_scene();
  io::SparseGridOptions so;
  so.threshold = 0.05;
  const io::SparseGrid grid = io::build_sparse_grid(scene.volume, Eigen::Vector3d(1.0, 1.0, 1.0), so);
  GaussianMixture start = scene.truth;
  for (auto& g : start) g.intensity_logit -= 0.8f;
  GmfOptions base;
  base.aggregation = Aggregation::kSum;  // these tests fit the report's sum
  base.iterations_per_round = 10;
  base.prune_intensity = 0.0;
  CompareOptions o;
  o.optimizers = {Optimizer::kLevenbergMarquardtCgnr, Optimizer::kAdam};
  o.adam_steps = 25;
  o.time_budget_s = 20;
  int lines = 0;
  const Comparison c = compare_optimizers(scene.volume, fit_samples(grid, base), grid.frame(), start, base, o,
                                          [&](const OptimizerRun&, const FitIteration&) { ++lines; });
  ASSERT_EQ(c.runs.size(), 2u);
  EXPECT_EQ(c.runs[0].name, "adam");
  EXPECT_EQ(c.runs[1].name, "lm-cgnr");
  EXPECT_EQ(c.adam_steps_done, 25);
  EXPECT_DOUBLE_EQ(c.target_loss, c.runs[0].final_loss);
  EXPECT_GT(lines, 25);
  for (const OptimizerRun& run : c.runs) {
    // Same start: the first logged loss is the same for every optimizer.
    EXPECT_NEAR(run.result.log.front().loss, c.runs[0].result.log.front().loss,
                1e-6 * c.runs[0].result.log.front().loss);
    EXPECT_EQ(run.gaussians, 6);
    ASSERT_GE(run.seconds_to_target, 0.0) << run.name;  // LM reaches Adam's 25-step loss on this easy scene
    for (const FitIteration& it : run.result.log) {
      if (it.seconds < run.seconds_to_target) {
        EXPECT_GT(it.loss, c.target_loss);
      }
    }
  }
}

TEST(GmfCompare, OptimizerNamesMatchTheConfig) {
  EXPECT_EQ(optimizer_name(Optimizer::kLevenbergMarquardt), "lm");
  EXPECT_EQ(optimizer_name(Optimizer::kDogleg), "dogleg");
  EXPECT_EQ(optimizer_name(Optimizer::kLbfgs), "lbfgs");
}

TEST(GmfCompare, EmptyListIsAnError) {
  const CompareScene scene = make_compare_scene();
  const io::SparseGrid grid = io::build_sparse_grid(scene.volume, Eigen::Vector3d(1.0, 1.0, 1.0), {});
  CompareOptions o;
  o.optimizers.clear();
  EXPECT_THROW(
      compare_optimizers(scene.volume, fit_samples(grid, GmfOptions{}), grid.frame(), scene.truth, GmfOptions{}, o),
      io::InputError);
}

}  // namespace
}  // namespace hisnegs::gmf
