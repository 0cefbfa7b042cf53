// SPDX-License-Identifier: Apache-2.0
// compare_optimizers on a tiny scene: Adam defines the target, every run starts
// from the same mixture, times to target are read from the runs' own logs.
#include "gmf/compare.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <span>
#include <string>
#include <vector>

#include "gmf/init.hpp"
#include "gmf/core/rasterize.hpp"
#include "io/error.hpp"
#include "io/sparse_grid.hpp"

namespace hisnegs::gmf {
namespace {

struct CompareScene {
  io::Volume volume;
  io::WorldFrame frame;
  GaussianMixture truth;
  io::SparseGrid grid;    // of the volume, threshold 0.05
  GaussianMixture start;  // the truth, each Gaussian dimmer
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
  io::SparseGridOptions so;
  so.threshold = 0.05;
  s.grid = io::build_sparse_grid(s.volume, Eigen::Vector3d(1.0, 1.0, 1.0), so);
  s.start = s.truth;
  for (auto& g : s.start) g.intensity_logit -= 0.8f;
  return s;
}

TEST(GmfCompare, AdamDefinesTheTargetAndRunsFirst) {
  const CompareScene scene = make_compare_scene();
  const io::SparseGrid& grid = scene.grid;
  const GaussianMixture& start = scene.start;
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

// GmfOptions::report_beta changes what is logged, never what is solved: the same
// Adam or brick-LM run at β 8 logs the loss at β 64 (the first line is then the
// β-64 run's first line) and ends at the same mixture.
TEST(GmfFit, ReportBetaChangesWhatIsLoggedNotWhatIsSolved) {
  const CompareScene scene = make_compare_scene();
  const io::SparseGrid& grid = scene.grid;
  GaussianMixture start = scene.start;
  for (auto& g : start) g.mean[0] += 0.3f;
  for (const Optimizer optimizer : {Optimizer::kAdam, Optimizer::kBrickLm}) {
    GmfOptions base;
    base.optimizer = optimizer;
    base.beta_start = base.beta_end = 8.0;
    base.rounds = 2;
    base.iterations_per_round = 10;
    base.brick_iterations = 3;
    base.densify = false;
    base.prune_intensity = 0.0;
    const SampleSet samples = fit_samples(grid, base);
    GmfOptions reported = base, at64 = base;
    reported.report_beta = 64.0;
    at64.beta_start = at64.beta_end = 64.0;
    GaussianMixture a = start, b = start, c = start;
    const FitResult ra = fit_mixture(scene.volume, samples, grid.frame(), a, base);
    const FitResult rb = fit_mixture(scene.volume, samples, grid.frame(), b, reported);
    const FitResult rc = fit_mixture(scene.volume, samples, grid.frame(), c, at64);
    const std::string name = optimizer_name(optimizer);
    ASSERT_EQ(a.size(), b.size()) << name;
    const std::span<const float> pa = flat_params(a), pb = flat_params(b);
    EXPECT_EQ(std::vector<float>(pa.begin(), pa.end()), std::vector<float>(pb.begin(), pb.end())) << name;
    ASSERT_FALSE(rb.log.empty());
    EXPECT_NEAR(rb.log.front().loss, rc.log.front().loss, 1e-9 * rc.log.front().loss) << name;
    EXPECT_GT(std::abs(rb.log.front().loss - ra.log.front().loss), 1e-6 * ra.log.front().loss) << name;
    for (const FitIteration& it : rb.log) EXPECT_EQ(it.beta, 64.0) << name;
    for (const FitIteration& it : ra.log) EXPECT_EQ(it.beta, 8.0) << name;
  }
}

TEST(GmfFit, ReportBetaIsOnlyForSolversThatLogAtIt) {
  GmfOptions o;
  o.optimizer = Optimizer::kLevenbergMarquardtCgnr;
  o.report_beta = 64.0;
  EXPECT_THROW(o.validate(), io::InputError);  // the schedule starts at 8: LM-CGNR would log at 8
  o.beta_start = 64.0;
  EXPECT_NO_THROW(o.validate());  // solves at the β it reports
  CompareOptions c;
  c.continuation = {Optimizer::kLbfgs};
  EXPECT_THROW(c.validate(), io::InputError);
}

// With continuation, Adam and the brick LM follow the β schedule and the others
// solve at β_end; every run logs at β_end, from the same first loss.
TEST(GmfCompare, ContinuationRunsAreMeasuredOnTheFinalObjective) {
  const CompareScene scene = make_compare_scene();
  const io::SparseGrid& grid = scene.grid;
  const GaussianMixture& start = scene.start;
  GmfOptions base;  // the softmax, β 8 → 64
  base.prune_intensity = 0.0;
  base.brick_iterations = 3;
  CompareOptions o;
  o.optimizers = {Optimizer::kAdam, Optimizer::kBrickLm, Optimizer::kLbfgs};
  o.continuation = {Optimizer::kAdam, Optimizer::kBrickLm};
  o.adam_steps = 60;  // 25 steps at β 8, 25 at 16, 10 at 32
  o.time_budget_s = 5;
  const Comparison c = compare_optimizers(scene.volume, fit_samples(grid, base), grid.frame(), start, base, o);
  ASSERT_EQ(c.runs.size(), 3u);
  EXPECT_TRUE(c.runs[0].continuation);
  EXPECT_TRUE(c.runs[1].continuation);
  EXPECT_FALSE(c.runs[2].continuation);
  for (const OptimizerRun& run : c.runs) {
    ASSERT_FALSE(run.result.log.empty()) << run.name;
    EXPECT_NEAR(run.result.log.front().loss, c.runs[0].result.log.front().loss,
                1e-9 * c.runs[0].result.log.front().loss)
        << run.name;
    for (const FitIteration& it : run.result.log) EXPECT_EQ(it.beta, 64.0) << run.name;
    EXPECT_LT(run.final_loss, run.result.log.front().loss) << run.name;
  }
}

// A custom solver (gmf/round_solver.hpp) sees the round's problem: 11·K parameters
// inside their box, the objective whose value it logs, its limits; the registered
// `spg` runs beside Adam from the same first loss and lowers it.
TEST(GmfCompare, CustomAndRegisteredSolversRunOnTheSameProblem) {
  const CompareScene scene = make_compare_scene();
  const io::SparseGrid& grid = scene.grid;
  GmfOptions base;  // the softmax at β 64 for every run
  base.prune_intensity = 0.0;
  base.beta_start = 64.0;
  CompareOptions o;
  o.optimizers = {Optimizer::kAdam};
  o.adam_steps = 30;
  o.time_budget_s = 5;
  const NamedSolver* spg = find_registered_optimizer("spg");
  ASSERT_NE(spg, nullptr);
  o.custom.push_back(*spg);
  int calls = 0;
  NamedSolver probe{"probe", "one evaluation, checks the problem", [&](const RoundSolverProblem& p) {
                      ++calls;
                      EXPECT_EQ(p.x.size(), 11u * scene.start.size());
                      EXPECT_EQ(p.lower.size(), p.x.size());
                      for (std::size_t i = 0; i < p.x.size(); ++i) {
                        EXPECT_LE(p.lower[i], p.x[i]);
                        EXPECT_GE(p.upper[i], p.x[i]);
                      }
                      EXPECT_EQ(p.max_iterations, 25);
                      EXPECT_GT(p.seconds_left, 0.0);
                      EXPECT_LE(p.seconds_left, 5.0);
                      std::vector<double> g(p.x.size());
                      const double loss = p.objective.evaluate(p.x.data(), g.data());
                      (void)p.log(loss);
                      for (std::size_t i = 0; i < p.x.size(); ++i) {
                        if (std::isfinite(p.upper[i])) p.x[i] = p.upper[i] + 1.0;  // outside the box: clamped
                      }
                      return RoundSolverOutcome{.iterations = 1, .converged = true, .message = "probe: done"};
                    }};
  o.custom.push_back(probe);
  const Comparison c = compare_optimizers(scene.volume, fit_samples(grid, base), grid.frame(), scene.start, base, o);
  ASSERT_EQ(c.runs.size(), 3u);
  EXPECT_EQ(c.runs[1].name, "spg");
  EXPECT_EQ(c.runs[1].optimizer, Optimizer::kCustom);
  EXPECT_EQ(c.runs[2].name, "probe");
  const double first = c.runs[0].result.log.front().loss;
  for (const OptimizerRun& run : c.runs) {
    EXPECT_TRUE(run.failure.empty()) << run.name << ": " << run.failure;
    ASSERT_FALSE(run.result.log.empty()) << run.name;
    EXPECT_NEAR(run.result.log.front().loss, first, 1e-9 * first) << run.name;
    for (const FitIteration& it : run.result.log) EXPECT_EQ(it.beta, 64.0) << run.name;
  }
  EXPECT_LT(c.runs[1].final_loss, 0.5 * first);  // spg descends
  EXPECT_EQ(calls, 2);  // converged: the loop ends after round 1 (round 0 never ends a fit)
}

TEST(GmfCompare, CustomSolversNeedANameOfTheirOwn) {
  CompareOptions o;
  o.custom.push_back(NamedSolver{"adam", "", [](const RoundSolverProblem&) { return RoundSolverOutcome{}; }});
  EXPECT_THROW(o.validate(), io::InputError);  // a built-in's name
  o.custom[0].name = "mine";
  EXPECT_NO_THROW(o.validate());
  o.custom.push_back(o.custom[0]);
  EXPECT_THROW(o.validate(), io::InputError);  // twice
  GmfOptions g;
  g.optimizer = Optimizer::kCustom;
  EXPECT_THROW(g.validate(), io::InputError);  // no solver
}

TEST(GmfCompare, OptimizerNamesMatchTheConfig) {
  EXPECT_EQ(optimizer_name(Optimizer::kLevenbergMarquardt), "lm");
  EXPECT_EQ(optimizer_name(Optimizer::kDogleg), "dogleg");
  EXPECT_EQ(optimizer_name(Optimizer::kLbfgs), "lbfgs");
}

TEST(GmfCompare, EmptyListIsAnError) {
  const CompareScene scene = make_compare_scene();
  const io::SparseGrid& grid = scene.grid;
  CompareOptions o;
  o.optimizers.clear();
  EXPECT_THROW(
      compare_optimizers(scene.volume, fit_samples(grid, GmfOptions{}), grid.frame(), scene.truth, GmfOptions{}, o),
      io::InputError);
}

}  // namespace
}  // namespace hisnegs::gmf
