// SPDX-License-Identifier: Apache-2.0
// Crash safety of `hisnegs train`: the process is killed with SIGKILL at
// chosen moments (HISNEGS_FAULT, io/fault_injection.hpp), what it leaves behind is
// checked (every visible checkpoint complete, `latest` naming a complete pair), and
// `--resume` must then finish with exactly the parameters of an uninterrupted run.
#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <string>

#include "gmf/core/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {

namespace fs = std::filesystem;
using testing::run_hisnegs;

// 6 epochs of 106 views (one view per step), a checkpoint after every epoch,
// density control at epochs 2 and 4 with a threshold every Gaussian passes.
constexpr const char* kSchedule = R"(train:
  epochs: 6
  save_every: 1
  beta_warmup_epochs: 3
  densify_from: 2
  densify_every: 2
  densify_until: 4
  densify_grad_threshold: 1e-9
  max_gaussians: 400
  prune_every: 3
)";

class CrashSafeTraining : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new testing::ScratchDir;
    const fs::path d = dir_->path();
    testing::write_text(d / "t.yaml", kSchedule);
    ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", d / "s.tif", "--shape", "16,40,40"}).exit_code, 0);
    ASSERT_EQ(run_hisnegs({"-q", "fit", d / "s.tif", "-o", d / "m.ply", "--gaussians", "80", "--time-budget", "3",
                           "--optimizer", "adam"})
                  .exit_code,
              0);
    ASSERT_EQ(
        run_hisnegs({"-q", "gt", d / "s.tif", "-o", d / "gt", "--orbit", "both", "--size", "24", "--backend", "cpu"})
            .exit_code,
        0);
    const auto r = train("reference");
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static testing::CommandResult train(const std::string& run, bool resume = false) {
    const fs::path d = dir_->path();
    std::vector<std::string> args{"-q",     "--config", d / "t.yaml", "train", "--init",    d / "m.ply",
                                  "--data", d / "gt",   "-o",         d / run, "--backend", "cpu"};
    if (resume) args.push_back("--resume");
    return run_hisnegs(args);
  }

  // Kills a fresh run at `fault`, checks the leftovers, resumes, compares with the reference.
  static void kill_then_resume(const std::string& fault, const std::string& run) {
    const fs::path d = dir_->path(), checkpoints = d / run / "checkpoints";
    ::setenv("HISNEGS_FAULT", fault.c_str(), 1);
    const auto killed = train(run);
    ::unsetenv("HISNEGS_FAULT");
    ASSERT_EQ(killed.exit_code, 128 + 9) << fault << ": " << killed.err;
    ASSERT_FALSE(fs::exists(d / run / "final.ply")) << fault;
    // Every visible checkpoint file is complete; `latest` names a pair that exists.
    for (const auto& e : fs::directory_iterator(checkpoints)) {
      const std::string name = e.path().filename().string();
      if (name.starts_with(".")) continue;  // an interrupted write's temporary, never a checkpoint name
      if (e.path().extension() == ".ply") {
        EXPECT_NO_THROW((void)gmf::load_checkpoint(e.path().string())) << name;
      }
    }
    ASSERT_TRUE(fs::exists(checkpoints / "latest")) << fault;
    const int epoch = std::stoi(testing::read_bytes(checkpoints / "latest"));
    bool pair = false;
    for (const auto& e : fs::directory_iterator(checkpoints)) {
      pair = pair || e.path().filename().string().find(std::to_string(epoch)) != std::string::npos;
    }
    EXPECT_TRUE(pair) << fault << ": latest = " << epoch;

    const auto resumed = train(run, true);
    ASSERT_EQ(resumed.exit_code, 0) << fault << ": " << resumed.err;
    EXPECT_EQ(testing::read_bytes(d / run / "final.ply"), testing::read_bytes(d / "reference" / "final.ply")) << fault;
    for (const auto& e : fs::directory_iterator(checkpoints)) {
      EXPECT_FALSE(e.path().filename().string().starts_with(".")) << "stale temporary " << e.path();
    }
  }

  static testing::ScratchDir* dir_;
};

testing::ScratchDir* CrashSafeTraining::dir_ = nullptr;

TEST_F(CrashSafeTraining, KilledDuringAnEpoch) { kill_then_resume("train_step:300", "mid_epoch"); }  // epoch 3

TEST_F(CrashSafeTraining, KilledDuringACheckpointWrite) {
  kill_then_resume("checkpoint_write:3", "mid_checkpoint");  // epoch 3's model written, its state not
}

TEST_F(CrashSafeTraining, KilledBeforeAnAtomicRename) {
  // Writes per epoch: log.csv, model, state, latest; the 6th is epoch 2's model.
  kill_then_resume("atomic_commit:6", "mid_rename");
}

TEST_F(CrashSafeTraining, KilledDuringDensityControl) {
  kill_then_resume("densify:5", "mid_densify");  // epoch 2's density control, after 4 splits
}

}  // namespace
}  // namespace hisnegs
