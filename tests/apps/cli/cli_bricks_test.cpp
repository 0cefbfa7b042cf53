// SPDX-License-Identifier: Apache-2.0
// The bricked fit through the real binary (gmf/bricked/, driven by apps/pipeline/fit_stage.cpp):
// a stack cut into bricks fits to a model as good as the whole fit's; a fit killed
// (SIGKILL) between bricks resumes from the finished ones to the checkpoint of an
// uninterrupted run, byte for byte; a brick folder of another config is refused,
// and a damaged field of its plan.json is one line naming it;
// --max-memory that does not parse or is too small is one line, exit 2, nothing
// written; a write that fails (the file-size limit standing in for a full disk)
// stops the fit with the finished bricks intact.
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <regex>
#include <string>

#include <nlohmann/json.hpp>

#include "gmf/core/checkpoint.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {
namespace fs = std::filesystem;
using testing::run_hisnegs;

// A fixed schedule (no time budget reached): every brick is a pure function of its
// region, its share of K and its seed.
constexpr const char* kFixed =
    "gmf: {gaussians: 300, rounds: 3, iterations_per_round: 8, time_budget_s: 600, seam_iterations: 10}\n";

class BrickedFit : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new testing::ScratchDir;
    const fs::path d = dir_->path();
    testing::write_text(d / "fixed.yaml", kFixed);
    ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", d / "s.tif", "--shape", "20,72,80"}).exit_code, 0);
    const auto ref = fit("ref.ply");
    ASSERT_EQ(ref.exit_code, 0) << ref.err;
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  static fs::path dir() { return dir_->path(); }
  // A bricked fit of s.tif (cores of 32 voxels: 3 x 3 x 1 bricks).
  static testing::CommandResult fit(const std::string& out, std::vector<std::string> extra = {}) {
    std::vector<std::string> args{"--config", dir() / "fixed.yaml", "fit", dir() / "s.tif", "-o", dir() / out,
                                  "--brick-voxels", "32"};
    args.insert(args.end(), extra.begin(), extra.end());
    return run_hisnegs(args);
  }
  static int finished_bricks(const fs::path& folder) {
    int n = 0;
    for (const auto& e : fs::directory_iterator(folder)) n += e.path().extension() == ".json" &&
                                                                e.path().filename() != "plan.json";
    return n;
  }
  static inline testing::ScratchDir* dir_ = nullptr;
};

double psnr_3d_of(const std::string& out) {
  std::smatch m;
  const std::regex re("3D PSNR ([0-9.]+) dB");
  return std::regex_search(out, m, re) ? std::stod(m[1]) : -1.0;
}

TEST_F(BrickedFit, FitsAsWellAsTheWholeStackAndCleansUp) {
  const std::string log = testing::read_bytes(dir() / "ref.ply");
  EXPECT_NE(log.find("comment hisnegs bricks 3 x 3 x 1 = 9 bricks"), std::string::npos);
  EXPECT_FALSE(fs::exists(dir() / "ref.ply.bricks")) << "the brick folder outlives the checkpoint";
  const gmf::Checkpoint c = gmf::load_checkpoint(dir() / "ref.ply");
  EXPECT_GT(c.mixture.size(), 150u);
  // The same schedule on the whole stack: the bricked 3D PSNR is close.
  const auto bricked = fit("again.ply");
  ASSERT_EQ(bricked.exit_code, 0) << bricked.err;
  EXPECT_EQ(testing::read_bytes(dir() / "again.ply"), testing::read_bytes(dir() / "ref.ply")) << "not deterministic";
  const auto whole = run_hisnegs({"--config", dir() / "fixed.yaml", "fit", dir() / "s.tif", "-o", dir() / "whole.ply"});
  ASSERT_EQ(whole.exit_code, 0) << whole.err;
  const double b = psnr_3d_of(bricked.out + bricked.err), w = psnr_3d_of(whole.out + whole.err);
  ASSERT_GT(b, 0);
  ASSERT_GT(w, 0);
  EXPECT_GT(b, w - 1.0) << "bricked " << b << " dB, whole " << w << " dB";
}

// Pure bricks: one thread (the process pinned to one core; TBB sizes its pool by the
// affinity mask) writes the bytes that every core wrote.
TEST_F(BrickedFit, OneThreadWritesTheSameCheckpoint) {
  if (std::system("taskset -c 0 true 2>/dev/null") != 0) GTEST_SKIP() << "taskset is not available";
  const std::string command = "taskset -c 0 " + testing::shell_quoted(testing::hisnegs_exe()) + " -q --config " +
                              testing::shell_quoted(dir() / "fixed.yaml") + " fit " +
                              testing::shell_quoted(dir() / "s.tif") + " -o " +
                              testing::shell_quoted(dir() / "one.ply") + " --brick-voxels 32";
  const testing::ShellResult one = testing::run_shell(command);
  ASSERT_EQ(one.status, 0) << one.out;
  EXPECT_EQ(testing::read_bytes(dir() / "one.ply"), testing::read_bytes(dir() / "ref.ply"));
}

TEST_F(BrickedFit, AKilledFitResumesToTheUninterruptedCheckpoint) {
  ::setenv("HISNEGS_FAULT", "brick-save:4", 1);
  const auto killed = fit("k.ply");
  ::unsetenv("HISNEGS_FAULT");
  ASSERT_EQ(killed.exit_code, 128 + 9) << killed.err;
  EXPECT_FALSE(fs::exists(dir() / "k.ply"));
  EXPECT_EQ(finished_bricks(dir() / "k.ply.bricks"), 3);
  const auto resumed = fit("k.ply");
  ASSERT_EQ(resumed.exit_code, 0) << resumed.err;
  EXPECT_NE((resumed.out + resumed.err).find("3 of 9 bricks already finished"), std::string::npos) << resumed.out;
  EXPECT_EQ(testing::read_bytes(dir() / "k.ply"), testing::read_bytes(dir() / "ref.ply"));
}

TEST_F(BrickedFit, ABrickFolderOfAnotherConfigIsRefusedAndKept) {
  ::setenv("HISNEGS_FAULT", "brick-save:3", 1);
  ASSERT_EQ(fit("f.ply").exit_code, 128 + 9);
  ::unsetenv("HISNEGS_FAULT");
  const auto other = fit("f.ply", {"--gaussians", "200"});
  EXPECT_EQ(other.exit_code, 2) << other.err;
  EXPECT_EQ(testing::count_lines(other.err), 1) << other.err;
  EXPECT_NE(other.err.find("holds the bricks of another stack, config or plan"), std::string::npos) << other.err;
  EXPECT_EQ(finished_bricks(dir() / "f.ply.bricks"), 2) << "the other fit's bricks were touched";
  EXPECT_FALSE(fs::exists(dir() / "f.ply"));
}

// A plan.json of this fit whose statistics are damaged (a field of the wrong type)
// is one line naming the file and the field, exit 2; the finished bricks are kept.
TEST_F(BrickedFit, ADamagedFieldOfThePlanIsOneLineNamingIt) {
  ::setenv("HISNEGS_FAULT", "brick-save:3", 1);
  ASSERT_EQ(fit("p.ply").exit_code, 128 + 9);
  ::unsetenv("HISNEGS_FAULT");
  const fs::path plan = dir() / "p.ply.bricks" / "plan.json";
  const nlohmann::json good = nlohmann::json::parse(testing::read_bytes(plan));
  for (const std::string key : {"raw_lo", "core_foreground"}) {
    SCOPED_TRACE(key);
    nlohmann::json damaged_plan = good;  // a string where a number or a list of them belongs
    damaged_plan[key] = "damaged";
    testing::write_text(plan, damaged_plan.dump());
    const auto damaged = fit("p.ply");
    EXPECT_EQ(damaged.exit_code, 2) << damaged.err;
    EXPECT_EQ(testing::count_lines(damaged.err), 1) << damaged.err;
    EXPECT_NE(damaged.err.find("plan.json"), std::string::npos) << damaged.err;
    EXPECT_NE(damaged.err.find("field '" + key + "'"), std::string::npos) << damaged.err;
    EXPECT_EQ(finished_bricks(dir() / "p.ply.bricks"), 2);
    EXPECT_FALSE(fs::exists(dir() / "p.ply"));
  }
}

TEST_F(BrickedFit, MaxMemoryThatDoesNotParseOrIsTooSmallIsOneLine) {
  const auto lots = run_hisnegs({"fit", dir() / "s.tif", "-o", dir() / "m1.ply", "--max-memory", "lots"});
  EXPECT_EQ(lots.exit_code, 2);
  EXPECT_EQ(testing::count_lines(lots.err), 1) << lots.err;
  EXPECT_NE(lots.err.find("gmf.max_memory = 'lots'"), std::string::npos) << lots.err;
  const auto tiny = run_hisnegs({"fit", dir() / "s.tif", "-o", dir() / "m2.ply", "--max-memory", "1MiB"});
  EXPECT_EQ(tiny.exit_code, 2);
  EXPECT_EQ(testing::count_lines(tiny.err), 1) << tiny.err;
  EXPECT_NE(tiny.err.find("too small for this fit"), std::string::npos) << tiny.err;
  EXPECT_NE(tiny.err.find("allow at least"), std::string::npos) << tiny.err;
  EXPECT_FALSE(fs::exists(dir() / "m1.ply"));
  EXPECT_FALSE(fs::exists(dir() / "m2.ply"));
  EXPECT_FALSE(fs::exists(dir() / "m2.ply.bricks"));
}

// A full disk: the file-size limit (SIGXFSZ ignored, so write() fails with EFBIG)
// stops the resumed fit at its next brick; the finished bricks stay loadable and a
// later resume still ends at the uninterrupted checkpoint.
TEST_F(BrickedFit, AFailedBrickWriteLeavesTheFinishedBricksIntact) {
  ::setenv("HISNEGS_FAULT", "brick-save:3", 1);
  ASSERT_EQ(fit("d.ply").exit_code, 128 + 9);
  ::unsetenv("HISNEGS_FAULT");
  const std::string command = "ulimit -f 2 && trap '' XFSZ && exec " + testing::shell_quoted(testing::hisnegs_exe()) +
                              " -q --config " + testing::shell_quoted(dir() / "fixed.yaml") + " fit " +
                              testing::shell_quoted(dir() / "s.tif") + " -o " + testing::shell_quoted(dir() / "d.ply") +
                              " --brick-voxels 32";
  const testing::ShellResult full = testing::run_shell(command);
  EXPECT_NE(full.status, 0) << full.out;
  EXPECT_EQ(testing::count_lines(full.out), 1) << full.out;
  EXPECT_NE(full.out.find("File too large"), std::string::npos) << full.out;
  EXPECT_FALSE(fs::exists(dir() / "d.ply"));
  const int finished = finished_bricks(dir() / "d.ply.bricks");
  EXPECT_GE(finished, 2);
  for (const auto& e : fs::directory_iterator(dir() / "d.ply.bricks")) {
    if (e.path().extension() == ".ply") {
      EXPECT_NO_THROW((void)gmf::load_checkpoint(e.path())) << e.path();
    }
  }
  const auto resumed = fit("d.ply");
  ASSERT_EQ(resumed.exit_code, 0) << resumed.err;
  EXPECT_EQ(testing::read_bytes(dir() / "d.ply"), testing::read_bytes(dir() / "ref.ply"));
}

// `gt` of a stack read by bricks writes the whole-stack images, byte for byte.
// The time budget holds for many small bricks: the brick pass shares what is left
// after what a brick costs beside its fit (measured on the bricks done), and the
// seam pass leaves a brick as fitted once the budget is spent (or is skipped when
// nothing is left), saying so; the fit still ends with a whole checkpoint. (Bricks
// of 8 voxels: 3 x 9 x 10 = 270.)
TEST_F(BrickedFit, ManySmallBricksKeepToTheTimeBudget) {
  const auto r = run_hisnegs({"fit", dir() / "s.tif", "-o", dir() / "small.ply", "--brick-voxels", "8",
                              "--time-budget", "0.05"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string said = r.out + r.err;
  EXPECT_NE(said.find("the time budget (gmf.time_budget_s 0.05 s) was spent"),
            std::string::npos)
      << said;
  EXPECT_GT(gmf::load_checkpoint(dir() / "small.ply").mixture.size(), 0u);
}

TEST_F(BrickedFit, GroundTruthByBricksEqualsTheWholeStacks) {
  const auto whole = run_hisnegs({"-q", "gt", dir() / "s.tif", "-o", dir() / "gt_whole", "--orbit", "eval", "--size",
                                  "40", "--backend", "cpu"});
  ASSERT_EQ(whole.exit_code, 0) << whole.err;
  const auto bricks = run_hisnegs({"gt", dir() / "s.tif", "-o", dir() / "gt_bricks", "--orbit", "eval", "--size", "40",
                                   "--brick-voxels", "24"});
  ASSERT_EQ(bricks.exit_code, 0) << bricks.err;
  EXPECT_NE((bricks.out + bricks.err).find("read by bricks of 24 voxels"), std::string::npos) << bricks.out;
  EXPECT_EQ(testing::read_bytes(dir() / "gt_bricks" / "mips.tif"), testing::read_bytes(dir() / "gt_whole" / "mips.tif"));
  const auto tiny = run_hisnegs({"gt", dir() / "s.tif", "-o", dir() / "gt_tiny", "--max-memory", "1KiB"});
  EXPECT_EQ(tiny.exit_code, 2);
  EXPECT_EQ(testing::count_lines(tiny.err), 1) << tiny.err;
  EXPECT_NE(tiny.err.find("too small for gt"), std::string::npos) << tiny.err;
  EXPECT_FALSE(fs::exists(dir() / "gt_tiny"));
}

// A tiled BigTIFF cut short (tile offsets past its end): the statistics pass, which
// reads every tile by region, stops with one line naming the file; nothing written.
TEST(BrickedFitInput, ABigTiffWhoseTilesPointPastItsEndIsOneLine) {
  if (std::system("/usr/bin/python3 -c 'import tifffile, numpy' 2>/dev/null") != 0) {
    if (std::getenv("CI")) FAIL() << "python3-tifffile is missing; scripts/install-deps.sh installs it";
    GTEST_SKIP() << "python3 with tifffile is not installed";
  }
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,64,64"}).exit_code, 0);
  const auto r = testing::run_shell("cd " + testing::shell_quoted(dir.path()) +
                                    " && /usr/bin/python3 -c 'import tifffile, os\n"
                                    "a = tifffile.imread(\"s.tif\")\n"
                                    "tifffile.imwrite(\"t.tif\", a, bigtiff=True, tile=(32, 32))\n"
                                    "n = os.path.getsize(\"t.tif\")\n"
                                    "os.truncate(\"t.tif\", n * 2 // 3)'");
  ASSERT_EQ(r.status, 0) << r.out;
  const auto fit = run_hisnegs({"fit", dir / "t.tif", "-o", dir / "m.ply", "--brick-voxels", "32"});
  EXPECT_EQ(fit.exit_code, 2) << fit.err;
  EXPECT_EQ(testing::count_lines(fit.err), 1) << fit.err;
  EXPECT_NE(fit.err.find((dir / "t.tif").string()), std::string::npos) << fit.err;
  EXPECT_FALSE(fs::exists(dir / "m.ply"));
  EXPECT_FALSE(fs::exists(dir / "m.ply.bricks"));
}

}  // namespace
}  // namespace hisnegs
