// SPDX-License-Identifier: Apache-2.0
// check_stage_folder / clear_stage_folder: what a run wrote goes, anything else (a
// foreign file, a symlink, an input) stops the clearing before anything is removed.
#include "apps/pipeline/stage_folder.hpp"

#include <gtest/gtest.h>
#include <unistd.h>

#include <filesystem>
#include <string>

#include "apps/pipeline/eval_stage.hpp"
#include "apps/pipeline/train_stage.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::apps {
namespace {
namespace fs = std::filesystem;

// A training folder as a run leaves it, interrupted mid-write.
void write_training_folder(const fs::path& train) {
  for (const char* name : {"log.csv", "final.ply", "training_curve.png", ".hisnegs.lock", "checkpoints/latest",
                           "checkpoints/epoch_00025.ply", "checkpoints/state_00025.bin",
                           "checkpoints/.epoch_00050.ply.tmp-4242-3"}) {
    fs::create_directories((train / name).parent_path());
    testing::write_text(train / name, "x");
  }
}

// The message of the io::InputError `f` throws ("" when it throws none).
template <class F>
std::string refusal(F&& f) {
  try {
    f();
  } catch (const io::InputError& e) {
    return e.what();
  }
  return "";
}

TEST(StageFolder, ClearsExactlyWhatARunWrote) {
  testing::ScratchDir dir;
  write_training_folder(dir / "train");
  EXPECT_EQ(refusal([&] { check_stage_folder(dir.path(), TrainStage::kFolder, {}); }), "");
  clear_stage_folder(dir.path(), TrainStage::kFolder, {});
  EXPECT_FALSE(fs::exists(dir / "train"));
  clear_stage_folder(dir.path(), TrainStage::kFolder, {});  // nothing there: nothing to do
  fs::create_directories(dir / "eval" / "compare");
  for (const char* name : {"metrics.csv", "metrics.json", "compare/000.png", "compare/107.png"}) {
    testing::write_text(dir / "eval" / name, "x");
  }
  clear_stage_folder(dir.path(), EvalStage::kFolder, {});
  EXPECT_FALSE(fs::exists(dir / "eval"));
}

TEST(StageFolder, AForeignFileStopsTheClearingBeforeAnythingGoes) {
  testing::ScratchDir dir;
  const fs::path train = dir / "train";
  // Each foreign path and the entry the refusal names (a folder a run never makes is
  // itself foreign).
  for (const auto& [foreign, named] : {std::pair{"notes.txt", "notes.txt"},
                                       std::pair{"checkpoints/epoch_final.ply", "checkpoints/epoch_final.ply"},
                                       std::pair{"extra/log.csv", "extra"},
                                       std::pair{"checkpoints/latest.bak", "checkpoints/latest.bak"}}) {
    SCOPED_TRACE(foreign);
    write_training_folder(train);
    fs::create_directories((train / foreign).parent_path());
    testing::write_text(train / foreign, "mine");
    const std::string why = refusal([&] { clear_stage_folder(dir.path(), TrainStage::kFolder, {}); });
    EXPECT_NE(why.find((train / named).string() + ": not written by hisnegs run"), std::string::npos) << why;
    EXPECT_NE(why.find("move it out of the run folder or use another -o"), std::string::npos) << why;
    EXPECT_TRUE(fs::exists(train / foreign));
    EXPECT_TRUE(fs::exists(train / "final.ply"));  // nothing was removed
    fs::remove_all(train);
  }
}

TEST(StageFolder, SymlinksAndInputsAreNeverARunsOwn) {
  testing::ScratchDir dir;
  const fs::path train = dir / "train";
  write_training_folder(train);
  testing::write_text(dir / "precious.ply", "mine");
  fs::remove(train / "final.ply");
  fs::create_symlink(dir / "precious.ply", train / "final.ply");  // a run never makes a link
  EXPECT_NE(refusal([&] { clear_stage_folder(dir.path(), TrainStage::kFolder, {}); }).find("not written by hisnegs run"),
            std::string::npos);
  EXPECT_EQ(testing::read_bytes(dir / "precious.ply"), "mine");
  fs::remove(train / "final.ply");

  // The run's own volume, under a name a run writes, and any protected input.
  testing::write_text(train / "log.csv", "volume");
  EXPECT_NE(refusal([&] { clear_stage_folder(dir.path(), TrainStage::kFolder, train / "log.csv"); })
                .find("log.csv: is an input of this run"),
            std::string::npos);
  io::protect_input(train / "training_curve.png");
  EXPECT_NE(refusal([&] { clear_stage_folder(dir.path(), TrainStage::kFolder, {}); })
                .find("training_curve.png: is an input of this run"),
            std::string::npos);
  EXPECT_TRUE(fs::exists(train / "log.csv"));
  EXPECT_TRUE(fs::exists(train / "training_curve.png"));

  // A file where the folder should be is not the run's either.
  testing::write_text(dir / "eval", "a file");
  EXPECT_NE(refusal([&] { check_stage_folder(dir.path(), EvalStage::kFolder, {}); }).find("not written by hisnegs run"),
            std::string::npos);
}

}  // namespace
}  // namespace hisnegs::apps
