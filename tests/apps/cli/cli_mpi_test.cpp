// SPDX-License-Identifier: Apache-2.0
// hisnegs on several MPI ranks (apps/pipeline/distributed.hpp), launched by the
// build's mpiexec with 2 ranks (oversubscribed: CI has 2 cores): the bricked fit's
// checkpoint (bricks and seam pass shared by the ranks) equals one process's byte
// for byte; the ground truth by bricks equals
// the single-process march bit for bit; a command that does not run distributed
// is refused on every rank; a rank killed mid-fit ends the job, and the rerun
// resumes from the finished bricks to the uninterrupted checkpoint. Skipped in a
// build without MPI.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include "gmf/core/checkpoint.hpp"
#include "gmf/core/psnr.hpp"
#include "io/tiff_stack.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {
namespace fs = std::filesystem;
using testing::shell_quoted;

constexpr const char* kMpiexec = HISNEGS_TEST_MPIEXEC;

// A fixed schedule (no time budget: rounds x iterations alone): the checkpoint is
// a pure function of the bricks, whatever the number of ranks.
constexpr const char* kMpiFixed =
    "gmf: {gaussians: 300, rounds: 3, iterations_per_round: 8, time_budget_s: 0, seam_iterations: 10}\n";

class Mpi : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (std::string(kMpiexec).empty() || !fs::exists(kMpiexec)) return;
    dir_ = new testing::ScratchDir;
    testing::write_text(dir() / "fixed.yaml", kMpiFixed);
    ASSERT_EQ(testing::run_hisnegs({"-q", "synth", "-o", dir() / "s.tif", "--shape", "20,72,80"}).exit_code, 0);
  }
  static void TearDownTestSuite() {
    delete dir_;
    dir_ = nullptr;
  }
  void SetUp() override {
    if (!dir_) GTEST_SKIP() << "built without MPI (or its mpiexec is gone): the distributed paths are not tested";
  }
  static fs::path dir() { return dir_->path(); }
  // `hisnegs ARGS` on `ranks` ranks; `env` (NAME=VALUE ...) for the last rank only,
  // and `last_args` instead of `args` there when not empty.
  static testing::ShellResult mpirun(int ranks, const std::vector<std::string>& args, const std::string& env = "",
                                     const std::vector<std::string>& last_args = {}) {
    const auto command_of = [](const std::vector<std::string>& a) {
      std::string c = shell_quoted(testing::hisnegs_exe());
      for (const std::string& s : a) c += " " + shell_quoted(s);
      return c;
    };
    const std::string hisnegs = command_of(args);
    // Bounded: a job whose ranks wait for each other forever fails the test instead of CI.
    const std::string launcher = "timeout 300 " + std::string(kMpiexec) + " --oversubscribe --allow-run-as-root ";
    std::string command = "cd " + shell_quoted(dir()) + " && " + launcher;
    if (env.empty() && last_args.empty()) {
      command += "-np " + std::to_string(ranks) + " " + hisnegs;
    } else {  // MPMD: the same program, the last rank with its own environment or arguments
      command += "-np " + std::to_string(ranks - 1) + " " + hisnegs + " : -np 1 " + (env.empty() ? "" : "env " + env + " ") +
                 command_of(last_args.empty() ? args : last_args);
    }
    return testing::run_shell(command + " 2>&1");
  }
  static std::vector<std::string> fit_args(const std::string& out) {
    return {"--config", (dir() / "fixed.yaml").string(), "fit", (dir() / "s.tif").string(), "-o",
            (dir() / out).string(), "--brick-voxels", "32"};
  }
  static inline testing::ScratchDir* dir_ = nullptr;
};

TEST_F(Mpi, TwoRanksFitTheCheckpointOfOneProcessByteForByte) {
  const auto one = testing::run_hisnegs(fit_args("one.ply"));
  ASSERT_EQ(one.exit_code, 0) << one.err;
  const auto two = mpirun(2, fit_args("two.ply"));
  ASSERT_EQ(two.status, 0) << two.out;
  EXPECT_NE(two.out.find("2 ranks share 9 bricks to fit"), std::string::npos) << two.out;
  EXPECT_NE(two.out.find("rank 1 of 2: fit: brick "), std::string::npos) << "rank 1 fitted nothing:\n" << two.out;
  EXPECT_NE(two.out.find("seam pass on 2 ranks"), std::string::npos) << two.out;
  EXPECT_EQ(testing::read_bytes(dir() / "two.ply"), testing::read_bytes(dir() / "one.ply"));
  // The seam pass sends each refitted brick's Gaussians near a later brick to that
  // brick's rank only: less than the whole model (what sending every refitted brick
  // to every rank would be).
  const auto exchanged = two.out.find(" MiB exchanged");
  ASSERT_NE(exchanged, std::string::npos) << two.out;
  const double mib = std::stod(two.out.substr(two.out.rfind("; ", exchanged) + 2));
  const auto wrote = two.out.find(": K ");
  ASSERT_NE(wrote, std::string::npos) << two.out;
  const std::size_t k = std::stoul(two.out.substr(wrote + 4));
  EXPECT_GT(k, 0u);
  EXPECT_LT(mib * 1048576.0, 44.0 * static_cast<double>(k)) << two.out;
  EXPECT_FALSE(fs::exists(dir() / "two.ply.bricks")) << "the brick folder outlives the checkpoint";
}

TEST_F(Mpi, TwoRanksMarchTheGroundTruthOfOneProcessBitForBit) {
  ASSERT_EQ(testing::run_hisnegs({"-q", "gt", dir() / "s.tif", "-o", dir() / "gt1", "--orbit", "eval", "--backend",
                                  "cpu"}).exit_code,
            0);
  const auto two = mpirun(2, {"gt", (dir() / "s.tif").string(), "-o", (dir() / "gt2").string(), "--orbit", "eval"});
  ASSERT_EQ(two.status, 0) << two.out;
  EXPECT_NE(two.out.find("2 MPI ranks share bricks of"), std::string::npos) << two.out;
  ASSERT_TRUE(fs::exists(dir() / "gt2" / "mips.tif")) << two.out;
  EXPECT_EQ(testing::read_bytes(dir() / "gt2" / "mips.tif"), testing::read_bytes(dir() / "gt1" / "mips.tif"));
}

TEST_F(Mpi, ACommandThatDoesNotRunDistributedIsRefused) {
  const auto info = mpirun(2, {"info", (dir() / "s.tif").string()});
  EXPECT_NE(info.status, 0);
  EXPECT_NE(info.out.find("hisnegs: error: 'info' does not run on several MPI ranks (2 launched)"), std::string::npos)
      << info.out;
}

// Rank 1 is killed (SIGKILL) as it saves its second brick: the job ends (the
// launcher names rank 1, rank 0 says what it was doing when stopped and which brick
// rank 1 died holding), the finished
// bricks stay, and the rerun names the brick the dead rank held and resumes to the
// uninterrupted checkpoint.
TEST_F(Mpi, AKilledRankEndsTheJobAndTheRerunResumes) {
  if (!fs::exists(dir() / "one.ply")) {  // each test may run in a process of its own
    ASSERT_EQ(testing::run_hisnegs(fit_args("one.ply")).exit_code, 0);
  }
  const auto killed = mpirun(2, fit_args("k.ply"), "HISNEGS_FAULT=brick-save:2");
  EXPECT_NE(killed.status, 0) << killed.out;
  EXPECT_FALSE(fs::exists(dir() / "k.ply"));
  ASSERT_TRUE(fs::exists(dir() / "k.ply.bricks")) << killed.out;
  // The launcher names the dead rank; the rank it stopped says what it was doing.
  EXPECT_NE(killed.out.find("process rank 1"), std::string::npos) << killed.out;
  EXPECT_NE(killed.out.find("hisnegs: rank 0 of 2: stopped while "), std::string::npos) << killed.out;
  // Rank 0 watches rank 1 and names the brick it died holding, in one line.
  EXPECT_NE(killed.out.find("hisnegs: rank 1 of 2 died (killed, crashed or out of memory) while fitting brick "),
            std::string::npos)
      << killed.out;
  const auto rerun = mpirun(2, fit_args("k.ply"));
  ASSERT_EQ(rerun.status, 0) << rerun.out;
  EXPECT_NE(rerun.out.find("bricks already finished"), std::string::npos) << rerun.out;
  EXPECT_NE(rerun.out.find("rank 1 of 2 died (killed, crashed or out of memory) while fitting brick "),
            std::string::npos)
      << rerun.out;
  EXPECT_EQ(testing::read_bytes(dir() / "k.ply"), testing::read_bytes(dir() / "one.ply"));
}

// Rank 1 is killed (SIGKILL) between bricks, as the seam pass starts: rank 0 names
// what it was doing (not only its own "stopped while ..."), and the rerun says it
// and resumes to the uninterrupted checkpoint.
TEST_F(Mpi, ARankKilledBetweenBricksIsNamedWithWhatItWasDoing) {
  if (!fs::exists(dir() / "one.ply")) {
    ASSERT_EQ(testing::run_hisnegs(fit_args("one.ply")).exit_code, 0);
  }
  const auto killed = mpirun(2, fit_args("ks.ply"), "HISNEGS_FAULT=seam-pass:1");
  EXPECT_NE(killed.status, 0) << killed.out;
  const std::string died = "rank 1 of 2 died (killed, crashed or out of memory) while refitting the seams between bricks";
  EXPECT_NE(killed.out.find("hisnegs: " + died), std::string::npos) << killed.out;
  const auto rerun = mpirun(2, fit_args("ks.ply"));
  ASSERT_EQ(rerun.status, 0) << rerun.out;
  EXPECT_NE(rerun.out.find("fit: the previous run's " + died), std::string::npos) << rerun.out;
  EXPECT_EQ(testing::read_bytes(dir() / "ks.ply"), testing::read_bytes(dir() / "one.ply"));
}

// A model and its 30 evaluation views at 48 x 48 for the render and training tests
// (one process makes them; made once per test process).
void make_model_and_views(const fs::path& dir) {
  if (fs::exists(dir / "gts" / "mips.tif")) return;
  testing::write_text(dir / "small.yaml",
                      "gmf: {gaussians: 200, rounds: 2, iterations_per_round: 8, time_budget_s: 0}\n"
                      "camera: {width: 48, height: 48}\n"
                      "train: {epochs: 3, views_per_step: 4, save_every: 1, lr_initial: 0.001}\n");
  const fs::path config = dir / "small.yaml";
  ASSERT_EQ(testing::run_hisnegs({"-q", "--config", config, "fit", dir / "s.tif", "-o", dir / "m.ply"}).exit_code, 0);
  ASSERT_EQ(testing::run_hisnegs({"-q", "--config", config, "gt", dir / "s.tif", "-o", dir / "gts", "--orbit", "eval",
                                  "--backend", "cpu"}).exit_code,
            0);
}

// Each rank splats its share of the Gaussians: the hard MIPs meet in a max (bit for
// bit one process's), the soft MIPs by merging their softmax states (>= 80 dB).
TEST_F(Mpi, TwoRanksRenderTheImagesOfOneProcess) {
  make_model_and_views(dir());
  for (const std::string mode : {"hard", "soft"}) {
    const std::vector<std::string> args = {"--config", (dir() / "small.yaml").string(), "render", "--model",
                                           (dir() / "m.ply").string(), "--cameras",
                                           (dir() / "gts" / "cameras.json").string(), "--mode", mode, "--backend",
                                           "cpu", "-o"};
    std::vector<std::string> one = args, two = args;
    one.push_back((dir() / ("r1" + mode)).string());
    two.push_back((dir() / ("r2" + mode)).string());
    ASSERT_EQ(testing::run_hisnegs(one).exit_code, 0);
    const auto run = mpirun(2, two);
    ASSERT_EQ(run.status, 0) << run.out;
    EXPECT_NE(run.out.find("2 MPI ranks, each renders its share"), std::string::npos) << run.out;
    const fs::path a = dir() / ("r1" + mode) / "render.tif", b = dir() / ("r2" + mode) / "render.tif";
    ASSERT_TRUE(fs::exists(b)) << run.out;
    if (mode == "hard") {
      EXPECT_EQ(testing::read_bytes(b), testing::read_bytes(a));
    } else {
      EXPECT_GE(gmf::psnr(io::read_tiff_stack(b).voxels, io::read_tiff_stack(a).voxels), 80.0);
    }
  }
}

// Data-parallel training: 2 ranks share each step's 4 views; the result equals one
// process's to float rounding (the gradient sums run in another order), the ranks
// agree after every epoch (checked by a hash), and rank 0 alone wrote the run.
TEST_F(Mpi, TwoRanksTrainTheModelOfOneProcessWithinRounding) {
  make_model_and_views(dir());
  const auto args = [&](const std::string& out) {
    return std::vector<std::string>{"--config", (dir() / "small.yaml").string(), "train", "--init",
                                    (dir() / "m.ply").string(), "--data", (dir() / "gts").string(), "--backend",
                                    "cpu", "-o", (dir() / out).string()};
  };
  ASSERT_EQ(testing::run_hisnegs(args("t1")).exit_code, 0);
  const auto run = mpirun(2, args("t2"));
  ASSERT_EQ(run.status, 0) << run.out;
  EXPECT_NE(run.out.find("2 MPI ranks share the 4 views of each step"), std::string::npos) << run.out;
  const gmf::Checkpoint one = gmf::load_checkpoint((dir() / "t1" / "final.ply").string());
  const gmf::Checkpoint two = gmf::load_checkpoint((dir() / "t2" / "final.ply").string());
  ASSERT_EQ(one.mixture.size(), two.mixture.size());
  const auto p1 = gmf::flat_params(one.mixture), p2 = gmf::flat_params(two.mixture);
  double worst = 0;
  for (std::size_t i = 0; i < p1.size(); ++i) worst = std::max(worst, std::abs(static_cast<double>(p1[i]) - p2[i]));
  EXPECT_LT(worst, 1e-4) << "largest parameter difference after 3 epochs";
  EXPECT_NE(worst, 0.0) << "equal bits: were the steps shared at all?";
  const std::string log1 = testing::read_bytes(dir() / "t1" / "log.csv"), log2 = testing::read_bytes(dir() / "t2" / "log.csv");
  EXPECT_EQ(std::count(log1.begin(), log1.end(), '\n'), std::count(log2.begin(), log2.end(), '\n'));
  // Resume works as in one process: 2 more epochs from the last checkpoint.
  std::vector<std::string> more = args("t2");
  more.insert(more.end(), {"--resume", "--epochs", "5"});
  const auto resumed = mpirun(2, more);
  ASSERT_EQ(resumed.status, 0) << resumed.out;
  const std::string log3 = testing::read_bytes(dir() / "t2" / "log.csv");
  EXPECT_EQ(std::count(log3.begin(), log3.end(), '\n'), std::count(log1.begin(), log1.end(), '\n') + 2) << log3;
}

// A rank that cannot open the volume (here: its path names no file) ends the job
// with its one line before any work: no brick folder, no checkpoint.
TEST_F(Mpi, ARankThatCannotOpenTheVolumeFailsTheJobBeforeAnyWork) {
  std::vector<std::string> bad = fit_args("nv.ply");
  bad[3] = (dir() / "missing.tif").string();
  const auto run = mpirun(2, fit_args("nv.ply"), "", bad);
  EXPECT_NE(run.status, 0) << run.out;
  EXPECT_NE(run.out.find("hisnegs: rank 1 of 2: error: "), std::string::npos) << run.out;
  EXPECT_NE(run.out.find("missing.tif"), std::string::npos) << run.out;
  EXPECT_FALSE(fs::exists(dir() / "nv.ply"));
  EXPECT_FALSE(fs::exists(dir() / "nv.ply.bricks")) << "rank 0 started work:\n" << run.out;
}

}  // namespace
}  // namespace hisnegs
