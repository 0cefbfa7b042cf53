// SPDX-License-Identifier: Apache-2.0
// run_pipeline in-process on a tiny synthetic stack: every declared output, then the
// reuse rules: a second run reuses every stage, a training setting redoes training
// and what follows it only, an orbit setting the orbit only, --force everything.
#include "apps/pipeline/run_pipeline.hpp"

#include <gtest/gtest.h>

#include <fstream>
#include <string>
#include <vector>

#include "apps/pipeline/synthetic_stack.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::apps {
namespace {

namespace fs = std::filesystem;

// A pipeline small enough for a test (as tests/apps/cli/cli_run_test.cpp): 40x40x16
// stack, 32x32 views, an Adam fit of 150 Gaussians for at most 3 s, 3 training epochs.
AppConfig tiny_config() {
  AppConfig c;
  c.synth.nx = 40;
  c.synth.ny = 40;
  c.synth.nz = 16;
  c.camera.width = c.camera.height = 32;
  c.gmf.optimizer = gmf::Optimizer::kAdam;
  c.gmf.gaussians = 150;
  c.gmf.time_budget_s = 3;
  c.gmf.rounds = 2;
  c.gmf.iterations_per_round = 10;
  c.train.epochs = 3;
  c.train.beta_warmup_epochs = 2;
  c.train.densify_from = 2;
  c.train.densify_every = 2;
  c.train.densify_until = 3;
  c.train.prune_every = 2;
  c.train.save_every = 1;
  return c;
}

// Progress that keeps the lines.
struct Lines {
  std::vector<std::string> lines;
  Progress progress() {
    Progress p;
    p.line = [this](std::string_view line) { lines.emplace_back(line); };
    return p;
  }
};

std::vector<std::string> names(const RunSummary& summary, bool reused) {
  std::vector<std::string> out;
  for (const StageTiming& t : summary.stages) {
    if (t.reused == reused) out.push_back(t.name);
  }
  return out;
}

template <RunStage... Stages>
std::vector<std::string> declared_outputs(StageList<Stages...>) {
  std::vector<std::string> outputs;
  (outputs.insert(outputs.end(), Stages::kOutputs.begin(), Stages::kOutputs.end()), ...);
  return outputs;
}

class RunPipeline : public ::testing::Test {
 protected:
  void SetUp() override {
    write_synthetic_stack(dir_ / "s.tif", SyntheticConfig(config_), Progress{});
    request_ = {dir_ / "s.tif", dir_ / "run", splat::Backend::kCpu, false, 6, 30.0};
    first_ = run_pipeline(request_, config_, Progress{});
  }
  RunSummary again(const AppConfig& config, const RunRequest& request) {
    return run_pipeline(request, config, lines_.progress());
  }
  const fs::path& out() const { return request_.dir; }

  testing::ScratchDir dir_;
  AppConfig config_ = tiny_config();
  RunRequest request_;
  RunSummary first_;
  Lines lines_;
};

using V = std::vector<std::string>;

TEST_F(RunPipeline, FirstRunWritesEveryDeclaredOutput) {
  EXPECT_EQ(names(first_, false), (V{"volume", "ground_truth", "fit", "train", "eval", "orbit"}));
  for (const std::string& output : declared_outputs(PipelineStages{})) {
    EXPECT_TRUE(fs::is_regular_file(out() / output)) << output;
  }
  for (const char* f : {"run.json", "config.yaml", "report.md"}) EXPECT_TRUE(fs::is_regular_file(out() / f)) << f;
  EXPECT_EQ(testing::csv_data_rows(out() / "train" / "log.csv"), 3);
}

TEST_F(RunPipeline, SecondRunReusesEveryStage) {
  const auto fit_time = fs::last_write_time(out() / "gmf.ply");
  const auto train_time = fs::last_write_time(out() / "train" / "final.ply");
  const RunSummary summary = again(config_, request_);
  EXPECT_EQ(names(summary, true), (V{"volume", "ground_truth", "fit", "train", "eval", "orbit"}));
  EXPECT_EQ(fs::last_write_time(out() / "gmf.ply"), fit_time);
  EXPECT_EQ(fs::last_write_time(out() / "train" / "final.ply"), train_time);
  ASSERT_FALSE(lines_.lines.empty());
  EXPECT_EQ(lines_.lines.front().rfind("run: [1/6] volume: normalize, aspect-correct, sparse grid: reused (", 0), 0u)
      << lines_.lines.front();
}

TEST_F(RunPipeline, TrainingChangeRedoesTrainingAndWhatFollows) {
  const auto fit_time = fs::last_write_time(out() / "gmf.ply");
  AppConfig longer = config_;
  longer.train.epochs = 4;
  const RunSummary summary = again(longer, request_);
  EXPECT_EQ(names(summary, true), (V{"volume", "ground_truth", "fit"}));
  EXPECT_EQ(names(summary, false), (V{"train", "eval", "orbit"}));
  EXPECT_EQ(fs::last_write_time(out() / "gmf.ply"), fit_time);
  EXPECT_EQ(testing::csv_data_rows(out() / "train" / "log.csv"), 4);
}

TEST_F(RunPipeline, OrbitSettingRedoesTheOrbitOnly) {
  RunRequest more_frames = request_;
  more_frames.orbit_frames = 4;
  const RunSummary summary = again(config_, more_frames);
  EXPECT_EQ(names(summary, false), V{"orbit"});
}

TEST_F(RunPipeline, ForceRedoesEveryStage) {
  RunRequest force = request_;
  force.force = true;
  ::testing::internal::CaptureStdout();
  ::testing::internal::CaptureStderr();
  const RunSummary summary = run_pipeline(force, config_, Progress{});
  // The stages speak only through Progress: an empty one prints nothing.
  EXPECT_EQ(::testing::internal::GetCapturedStdout(), "");
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
  EXPECT_TRUE(names(summary, true).empty());
  EXPECT_EQ(names(summary, false).size(), 6u);
}

}  // namespace
}  // namespace hisnegs::apps
