// SPDX-License-Identifier: Apache-2.0
// `hisnegs run`, `hisnegs demo` and `hisnegs bench report` through the real binary
// on a tiny synthetic stack: every promised file, finite metrics above a floor,
// stage reuse, re-running what a config change touches, resuming an interrupted
// training, and one-line errors.
#include <gtest/gtest.h>

#include <fstream>
#include <nlohmann/json.hpp>
#include <span>
#include <string>
#include <tuple>
#include <vector>

#include "io/sparse_grid.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {

namespace fs = std::filesystem;
using testing::run_hisnegs;
using Json = nlohmann::json;

// A pipeline small enough for a test: 40x40x16 stack, 32x32 views, an Adam fit of
// 150 Gaussians for at most 3 s, 3 training epochs.
constexpr const char* kTinyPipeline = R"(synth:
  nx: 40
  ny: 40
  nz: 16
camera:
  width: 32
  height: 32
gmf:
  optimizer: adam
  gaussians: 150
  time_budget_s: 3
  rounds: 2
  iterations_per_round: 10
train:
  epochs: 3
  beta_warmup_epochs: 2
  densify_from: 2
  densify_every: 2
  densify_until: 3
  prune_every: 2
  save_every: 1
)";

Json read_json(const fs::path& path) {
  std::ifstream in(path);
  return Json::parse(in);
}

// "run: [i/6] TITLE: reused" lines in `out`.
int reused_stages(const std::string& out) {
  int n = 0;
  for (std::size_t at = out.find(": reused ("); at != std::string::npos; at = out.find(": reused (", at + 1)) ++n;
  return n;
}

class CliRun : public ::testing::Test {
 protected:
  void SetUp() override {
    testing::write_text(dir_ / "tiny.yaml", kTinyPipeline);
    ASSERT_EQ(run_hisnegs({"--config", dir_ / "tiny.yaml", "-q", "synth", "-o", dir_ / "s.tif"}).exit_code, 0);
  }
  testing::CommandResult run(const std::vector<std::string>& extra = {}, const std::string& config = "tiny.yaml") {
    std::vector<std::string> args{"--config",   dir_ / config, "run", dir_ / "s.tif",   "-o",
                                  dir_ / "run", "--backend",   "cpu", "--orbit-frames", "6"};
    args.insert(args.end(), extra.begin(), extra.end());
    return run_hisnegs(args);
  }
  testing::ScratchDir dir_;
};

TEST_F(CliRun, WritesEveryOutputThenReusesFinishedStages) {
  auto r = run();
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  const fs::path out = dir_ / "run";
  for (const char* f : {"report.md", "run.json", "config.yaml", "volume.vdb", "volume.json", "gt/train/mips.tif",
                        "gt/train/cameras.json", "gt/eval/mips.tif", "gmf.ply", "fit_log.csv", "train/final.ply",
                        "train/log.csv", "train/training_curve.png", "eval/metrics.json", "eval/metrics.csv",
                        "eval/compare/000.png", "orbit.gif", "orbit.json"}) {
    EXPECT_TRUE(fs::is_regular_file(out / f)) << f;
  }
  EXPECT_EQ(reused_stages(r.out), 0) << r.out;
  EXPECT_EQ(testing::csv_data_rows(out / "train" / "log.csv"), 3);
  EXPECT_EQ(testing::csv_data_rows(out / "eval" / "metrics.csv"), 30);
  const Json metrics = read_json(out / "eval" / "metrics.json");
  const double psnr = metrics["psnr"]["mean"].get<double>();
  // A 3-epoch model of a 40x40x16 stack at 32x32 is coarse, but far from noise.
  EXPECT_TRUE(std::isfinite(psnr));
  EXPECT_GT(psnr, 18.0);
  EXPECT_GT(metrics["ssim"]["mean"].get<double>(), 0.3);
  EXPECT_EQ(read_json(out / "orbit.json")["seconds_per_frame"].size(), 6u);
  // The halos against the run's stack (a small one: counted).
  ASSERT_TRUE(metrics.contains("halos")) << metrics.dump();
  EXPECT_LE(metrics["halos"]["count"].get<long long>(), metrics["gaussians"].get<long long>());
  EXPECT_GE(metrics["halos"]["noise"].get<double>(), 0.02);
  std::ifstream in(out / "report.md");
  const std::string report{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  for (const char* section : {"## Summary", "## Stages", "report Table 8", "report Table 3", "report Table 12",
                              "report Table 10", "train/training_curve.png", "orbit.gif",
                              "Halos (Gaussians brighter than the stack at their centre)"}) {
    EXPECT_NE(report.find(section), std::string::npos) << section;
  }

  // Again: every stage is reused and no output is rewritten.
  const auto fit_time = fs::last_write_time(out / "gmf.ply");
  const auto train_time = fs::last_write_time(out / "train" / "final.ply");
  r = run();
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(reused_stages(r.out), 6) << r.out;
  EXPECT_EQ(fs::last_write_time(out / "gmf.ply"), fit_time);
  EXPECT_EQ(fs::last_write_time(out / "train" / "final.ply"), train_time);

  // A training setting changed: training and what follows it run again, the rest is reused.
  testing::write_text(dir_ / "longer.yaml",
                      std::string(kTinyPipeline).replace(std::string(kTinyPipeline).find("epochs: 3"), 9, "epochs: 4"));
  r = run({}, "longer.yaml");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(reused_stages(r.out), 3) << r.out;  // volume, ground truth, fit
  EXPECT_EQ(fs::last_write_time(out / "gmf.ply"), fit_time);
  EXPECT_EQ(testing::csv_data_rows(out / "train" / "log.csv"), 4);

  // --force redoes everything.
  r = run({"--force"}, "longer.yaml");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(reused_stages(r.out), 0) << r.out;

  // Training that wrecks the model (a step of 1): the report says final.ply is the fit.
  const std::string reported = "the fit itself, because training made the training views worse";
  EXPECT_EQ(report.find(reported), std::string::npos) << report;
  testing::write_text(dir_ / "wild.yaml", std::string(kTinyPipeline) + "  lr_initial: 1\n  lr_final: 1\n");
  r = run({}, "wild.yaml");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("training made them worse, so final.ply is the initial model"), std::string::npos) << r.out;
  std::ifstream wild_in(out / "report.md");
  const std::string wild{std::istreambuf_iterator<char>(wild_in), std::istreambuf_iterator<char>()};
  EXPECT_NE(wild.find(reported), std::string::npos) << wild;
}

// A stage output that another process rewrote (same bytes, a new file: what any
// atomic write leaves) is not the one the stage recorded: the stage and everything
// after it run again; the stages before it are reused.
TEST_F(CliRun, AnOutputWrittenByAnotherProcessIsNotReused) {
  ASSERT_EQ(run().exit_code, 0);
  const fs::path gmf = dir_ / "run" / "gmf.ply";
  fs::copy_file(gmf, dir_ / "copy.ply");
  fs::rename(dir_ / "copy.ply", gmf);
  const auto r = run();
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(reused_stages(r.out), 2) << r.out;  // volume and ground truth
  EXPECT_NE(r.out.find("run: [3/6] GMF fit (stage 1)\n"), std::string::npos) << r.out;
}

TEST_F(CliRun, ResumesAnInterruptedTraining) {
  ASSERT_EQ(run().exit_code, 0);
  // As if training had been killed after its last checkpoint: the record says
  // "started", there is no final model, the checkpoints are there.
  const fs::path run_dir = dir_ / "run";
  Json state = read_json(run_dir / "run.json");
  state["stages"]["train"]["state"] = "started";
  state["stages"]["train"]["seconds_before"] = 1.0;
  testing::write_text(run_dir / "run.json", state.dump());
  fs::remove(run_dir / "train" / "final.ply");
  ASSERT_TRUE(fs::exists(run_dir / "train" / "checkpoints" / "latest"));
  const auto r = run();
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("training (stage 2) (resuming)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("resuming after epoch 3"), std::string::npos) << r.out;
  EXPECT_EQ(reused_stages(r.out), 3) << r.out;  // volume, ground truth, fit; eval and orbit follow the new model
  EXPECT_TRUE(fs::is_regular_file(run_dir / "train" / "final.ply"));
  EXPECT_EQ(testing::csv_data_rows(run_dir / "train" / "log.csv"), 3);
}

// Every active voxel of one part of a grid: index and value, in the grid's order.
std::vector<std::tuple<int, int, int, float>> active_voxels(const io::SparseGrid& grid, io::SparseGridPart part) {
  std::vector<std::tuple<int, int, int, float>> out;
  grid.visit_active_leaves(part, [&](const std::array<int, 3>&, std::span<const io::ActiveVoxel> voxels) {
    for (const io::ActiveVoxel& v : voxels) out.emplace_back(v.index[0], v.index[1], v.index[2], v.value);
  });
  return out;
}

// A stack read in bricks (as one larger than --max-memory is): every stage runs, the
// stages share one streaming pass (stack_statistics.json), and the sparse grid and the
// ground truth are the whole stack's, byte for byte.
TEST_F(CliRun, ReadsTheStackInBricksWithTheSameGridAndGroundTruth) {
  const auto r = run({"--brick-voxels", "16"});
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  const fs::path out = dir_ / "run";
  for (const char* f : {"stack_statistics.json", "volume.vdb", "gt/eval/mips.tif", "gmf.ply", "train/final.ply",
                        "eval/metrics.json", "report.md"}) {
    EXPECT_TRUE(fs::is_regular_file(out / f)) << f;
  }
  for (const char* line : {"vdb: sparse grid of", "gt: ", "read by bricks of 16 voxels", "train: sparse grid of",
                           "3 x 3 x 1 = 9 bricks"}) {
    EXPECT_NE((r.out + r.err).find(line), std::string::npos) << line << "\n" << r.out << r.err;
  }
  const Json stats = read_json(out / "stack_statistics.json");
  EXPECT_LT(stats["raw_lo"].get<double>(), stats["raw_hi"].get<double>());
  // The whole stack, read at once by the standalone commands.
  const auto vdb = run_hisnegs({"--config", dir_ / "tiny.yaml", "-q", "vdb", dir_ / "s.tif", "-o", dir_ / "w.vdb"});
  ASSERT_EQ(vdb.exit_code, 0) << vdb.err;
  // (a .vdb file holds a UUID of its own: the grids are compared, not the bytes)
  const io::SparseGrid whole = io::read_vdb(dir_ / "w.vdb"), tiled = io::read_vdb(out / "volume.vdb");
  EXPECT_GT(whole.active_voxels(), 0);
  for (const auto part : {io::SparseGridPart::kForeground, io::SparseGridPart::kBackground}) {
    EXPECT_TRUE(active_voxels(whole, part) == active_voxels(tiled, part)) << "the grids differ";
  }
  const auto gt = run_hisnegs(
      {"--config", dir_ / "tiny.yaml", "-q", "gt", dir_ / "s.tif", "-o", dir_ / "gt", "--orbit", "eval", "--backend", "cpu"});
  ASSERT_EQ(gt.exit_code, 0) << gt.err;
  EXPECT_TRUE(testing::read_bytes(dir_ / "gt" / "mips.tif") == testing::read_bytes(out / "gt" / "eval" / "mips.tif"))
      << "the ground truth differs";
  // A --max-memory that cannot hold the smallest brick is refused before the run
  // folder is made.
  const auto small = run_hisnegs({"--config", dir_ / "tiny.yaml", "run", dir_ / "s.tif", "-o", dir_ / "small",
                                  "--backend", "cpu", "--max-memory", "1MiB"});
  EXPECT_EQ(small.exit_code, 2);
  EXPECT_EQ(testing::count_lines(small.err), 1) << small.err;
  EXPECT_NE(small.err.find("--max-memory = 1MiB: too small"), std::string::npos) << small.err;
  EXPECT_FALSE(fs::exists(dir_ / "small"));
}

TEST_F(CliRun, BadInputGetsOneLineErrors) {
  auto r = run_hisnegs({"run", dir_ / "missing.tif", "-o", dir_ / "run"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("missing.tif"), std::string::npos) << r.err;
  EXPECT_EQ(testing::count_lines(r.err), 1) << r.err;
  // A damaged stage record is named, not silently overwritten.
  fs::create_directories(dir_ / "run");
  testing::write_text(dir_ / "run" / "run.json", "{not json");
  r = run();
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("run.json"), std::string::npos) << r.err;
  EXPECT_EQ(testing::count_lines(r.err), 1) << r.err;
  // A stack the run itself writes (its ground truth) is refused before any stage.
  fs::create_directories(dir_ / "R" / "gt" / "train");
  fs::copy_file(dir_ / "s.tif", dir_ / "R" / "gt" / "train" / "mips.tif");
  r = run_hisnegs({"--config", dir_ / "tiny.yaml", "run", dir_ / "R" / "gt" / "train" / "mips.tif", "-o", dir_ / "R",
                   "--backend", "cpu"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("is a file of the run folder " + (dir_ / "R").string() + " that the run writes (gt)"),
            std::string::npos)
      << r.err;
  EXPECT_FALSE(fs::exists(dir_ / "R" / "volume.vdb"));
  EXPECT_FALSE(fs::exists(dir_ / "R" / "run.json"));
}

TEST(CliDemo, RunsThePipelineOnTheSyntheticNeuron) {
  testing::ScratchDir dir;
  testing::write_text(dir / "tiny.yaml", kTinyPipeline);
  // --config replaces the demo profile: the tiny pipeline instead of the few-minute one.
  const auto r = run_hisnegs({"--config", dir / "tiny.yaml", "demo", "-o", dir / "demo"});
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  for (const char* f : {"volume.tif", "volume.vdb", "gmf.ply", "train/final.ply", "eval/metrics.json", "report.md"}) {
    EXPECT_TRUE(fs::is_regular_file(dir / "demo" / f)) << f;
  }
  EXPECT_NE(r.out.find("demo: done"), std::string::npos) << r.out;
  // The synthetic stack is rewritten identically, so a second demo reuses everything.
  const auto again = run_hisnegs({"--config", dir / "tiny.yaml", "demo", "-o", dir / "demo"});
  ASSERT_EQ(again.exit_code, 0) << again.err;
  EXPECT_EQ(reused_stages(again.out), 6) << again.out;
}

TEST(CliBench, ReportWritesEveryTableWithTinySizes) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,32,32"}).exit_code, 0);
  const auto r = run_hisnegs(
      {"bench",        "report",  "-o",           dir / "b", "--volume",           dir / "s.tif", "--sizes",   "32,48",
       "--gaussians",  "300,600", "--betas",      "1,50",    "--orbit-frames",     "4",           "--views",   "2",
       "--min-frames", "2",       "--max-frames", "4",       "--seconds-per-case", "0.1",         "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err << r.out;
  EXPECT_EQ(testing::csv_data_rows(dir / "b" / "table7.csv"), 2);
  EXPECT_EQ(testing::csv_data_rows(dir / "b" / "table9.csv"), 2);
  EXPECT_EQ(testing::csv_data_rows(dir / "b" / "table10.csv"), 8);  // the frame-time statistics
  EXPECT_EQ(testing::csv_data_rows(dir / "b" / "table11.csv"), 2);
  EXPECT_GE(testing::csv_data_rows(dir / "b" / "table12.csv"), 2);
  std::ifstream in(dir / "b" / "report.md");
  const std::string report{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  for (const char* t : {"Machine:", "Table 7", "Table 9", "Table 10", "Table 11", "Table 12"}) {
    EXPECT_NE(report.find(t), std::string::npos) << t;
  }
  // Soft-MIP at beta 50 is much closer to the beta-1000 image than at beta 1.
  std::ifstream t11(dir / "b" / "table11.csv");
  std::string header, b1, b50;
  std::getline(t11, header);
  std::getline(t11, b1);
  std::getline(t11, b50);
  const double p1 = std::stod(b1.substr(b1.find(',') + 1)), p50 = std::stod(b50.substr(b50.find(',') + 1));
  EXPECT_GT(p50, p1 + 10.0) << b1 << " / " << b50;
}

}  // namespace
}  // namespace hisnegs
