// SPDX-License-Identifier: Apache-2.0
// The `compare-optimizers`, `render` and `bench render` commands through the real
// binary on tiny inputs: every promised file, its shape, and the bad-input errors.
#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <string>
#include <utility>

#include "gmf/core/checkpoint.hpp"
#include "io/gif.hpp"
#include "io/tiff_stack.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {

namespace fs = std::filesystem;
using testing::run_hisnegs;

int csv_rows(const fs::path& path) {
  std::ifstream in(path);
  int rows = -1;  // header
  for (std::string line; std::getline(in, line);) ++rows;
  return rows;
}

// A tiny stack, a GMF model of it (DIR/m.ply) and its ground truth (DIR/gt) at
// size x size for `orbit` (both: DIR/gt/train and DIR/gt/eval).
void make_model_and_ground_truth(const fs::path& dir, int size, const char* orbit) {
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,40,40"}).exit_code, 0);
  ASSERT_EQ(run_hisnegs({"-q", "fit", dir / "s.tif", "-o", dir / "m.ply", "--gaussians", "80", "--time-budget", "5"})
                .exit_code,
            0);
  ASSERT_EQ(run_hisnegs({"-q", "gt", dir / "s.tif", "-o", dir / "gt", "--orbit", orbit, "--size", std::to_string(size),
                         "--backend", "cpu"})
                .exit_code,
            0);
}

TEST(CliCompare, WritesTableCurvesSummaryAndPlot) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,40,40"}).exit_code, 0);
  testing::write_text(dir / "c.yaml", "gmf:\n  iterations_per_round: 4\n");
  const auto r =
      run_hisnegs({"--config", dir / "c.yaml", "compare-optimizers", dir / "s.tif", "-o", dir / "cmp", "--optimizers",
                   "lm-cgnr,adam,lbfgs", "--gaussians", "60", "--adam-steps", "8", "--time-budget", "20"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(csv_rows(dir / "cmp" / "results.csv"), 3);
  EXPECT_GT(csv_rows(dir / "cmp" / "curves.csv"), 8);
  std::ifstream md(dir / "cmp" / "summary.md");
  const std::string summary((std::istreambuf_iterator<char>(md)), std::istreambuf_iterator<char>());
  EXPECT_NE(summary.find("loss Adam reached after 8 steps"), std::string::npos) << summary;
  EXPECT_NE(summary.find("| lbfgs |"), std::string::npos);
  EXPECT_TRUE(fs::is_regular_file(dir / "cmp" / "loss_vs_time.png"));

  const auto bad = run_hisnegs({"compare-optimizers", dir / "s.tif", "-o", dir / "bad", "--optimizers", "adam,sgd"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("'sgd'"), std::string::npos) << bad.err;
  // A negative budget is an error before any work (it meant gmf.time_budget_s: 290 s each).
  for (const char* budget : {"-1", "0"}) {
    const auto neg = run_hisnegs({"compare-optimizers", dir / "s.tif", "-o", dir / "neg", "--time-budget", budget});
    EXPECT_EQ(neg.exit_code, 2) << budget;
    EXPECT_NE(neg.err.find("--time-budget"), std::string::npos) << neg.err;
    EXPECT_FALSE(fs::exists(dir / "neg")) << budget;
  }
}

// `bench report` options are checked before any table is measured: --views 0 wrote
// three tables, then failed with an internal error and no report.md.
TEST(CliRender, BenchReportOptionsAreCheckedFirst) {
  testing::ScratchDir dir;
  for (const std::vector<std::string>& extra : std::vector<std::vector<std::string>>{
           {"--views", "0"}, {"--orbit-frames", "0"}, {"--min-frames", "5", "--max-frames", "2"}}) {
    std::vector<std::string> args = {"bench", "report", "-o", (dir / "b").string()};
    args.insert(args.end(), extra.begin(), extra.end());
    const auto r = run_hisnegs(args);
    EXPECT_EQ(r.exit_code, 2) << extra[0];
    EXPECT_NE(r.err.find(extra[0]), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir / "b")) << extra[0];
  }
}

TEST(CliRender, WritesStackPreviewsMetaAndOrbit) {
  testing::ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(make_model_and_ground_truth(dir.path(), 32, "eval"));
  const auto r = run_hisnegs({"render", "--model", dir / "m.ply", "--cameras", dir / "gt" / "cameras.json", "-o",
                              dir / "r", "--backend", "cpu", "--orbit", "6", "--size", "24", "--mode", "hard"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("30 views of 32x32"), std::string::npos) << r.out;
  const io::TiffStackInfo info = io::inspect_tiff_stack(dir / "r" / "render.tif");
  EXPECT_EQ(info.nx, 32);
  EXPECT_EQ(info.ny, 32);
  EXPECT_EQ(info.nz, 30);
  EXPECT_EQ(info.type, io::SampleType::kFloat32);
  EXPECT_TRUE(fs::is_regular_file(dir / "r" / "previews" / "029.png"));
  EXPECT_TRUE(fs::is_regular_file(dir / "r" / "render.json"));
  const io::GifInfo gif = io::inspect_gif(dir / "r" / "orbit.gif");
  EXPECT_EQ(gif.frames, 6);
  EXPECT_EQ(gif.width, 24);
  // --lod: a model of one page is its own hierarchy's root: the same images, and
  // render.json says what each view drew; without --cameras it is refused.
  const auto lod = run_hisnegs({"render", "--model", dir / "m.ply", "--cameras", dir / "gt" / "cameras.json", "-o",
                                dir / "l", "--backend", "cpu", "--mode", "hard", "--lod", "1"});
  ASSERT_EQ(lod.exit_code, 0) << lod.err;
  EXPECT_NE(lod.out.find("level of detail: 1 nodes on 1 levels"), std::string::npos) << lod.out;
  EXPECT_EQ(testing::read_bytes(dir / "l" / "render.tif"), testing::read_bytes(dir / "r" / "render.tif"));
  EXPECT_NE(testing::read_bytes(dir / "l" / "render.json").find("\"gaussians_per_view\""), std::string::npos);
  // The hierarchy as a file: every command reads its model (the leaves); info shows the tree.
  const auto hgw = run_hisnegs({"export", "hierarchy", "--model", dir / "m.ply", "-o", dir / "m.hgw", "--page", "64"});
  ASSERT_EQ(hgw.exit_code, 0) << hgw.err;
  EXPECT_NE(hgw.out.find("nodes on 2 levels"), std::string::npos) << hgw.out;
  const auto shown = run_hisnegs({"info", dir / "m.hgw"});
  ASSERT_EQ(shown.exit_code, 0) << shown.err;
  EXPECT_NE(shown.out.find("hisnegs hierarchy (.hgw) version 1"), std::string::npos) << shown.out;
  EXPECT_NE(shown.out.find("gaussians    80"), std::string::npos) << shown.out;
  const auto from_file = run_hisnegs({"render", "--model", dir / "m.hgw", "--cameras", dir / "gt" / "cameras.json",
                                      "-o", dir / "h", "--backend", "cpu", "--mode", "hard", "--lod", "1"});
  ASSERT_EQ(from_file.exit_code, 0) << from_file.err;
  EXPECT_NE(from_file.out.find("nodes on 2 levels"), std::string::npos) << "the file's own tree: " << from_file.out;
  testing::write_text(dir / "bad.hgw", std::string("\x89HGW\r\n\x1a\n", 8) + std::string(40, '\0'));
  const auto bad = run_hisnegs({"info", dir / "bad.hgw"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_EQ(testing::count_lines(bad.err), 1) << bad.err;
  EXPECT_NE(bad.err.find("bad.hgw: hierarchy:"), std::string::npos) << bad.err;
  for (const char* bad : {"0", "nan", "-2"}) {
    const auto r = run_hisnegs({"render", "--model", dir / "m.ply", "--cameras", dir / "gt" / "cameras.json", "-o",
                                dir / "bad_lod", "--lod", bad});
    EXPECT_EQ(r.exit_code, 2) << bad;
    EXPECT_EQ(testing::count_lines(r.err), 1) << r.err;
    EXPECT_NE(r.err.find("--lod = "), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir / "bad_lod"));
  }
  const auto orbit_only = run_hisnegs({"render", "--model", dir / "m.ply", "-o", dir / "o", "--orbit", "4", "--lod", "1"});
  EXPECT_EQ(orbit_only.exit_code, 2);
  EXPECT_NE(orbit_only.err.find("--lod draws the views of --cameras"), std::string::npos) << orbit_only.err;
}

TEST(CliEval, WritesMetricsAndComparisonImages) {
  testing::ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(make_model_and_ground_truth(dir.path(), 32, "both"));
  const auto r =
      run_hisnegs({"eval", "--model", dir / "m.ply", "--data", dir / "gt", "-o", dir / "ev", "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("30 views of 32x32"), std::string::npos) << r.out;
  EXPECT_EQ(csv_rows(dir / "ev" / "metrics.csv"), 30);
  std::ifstream json(dir / "ev" / "metrics.json");
  const std::string text((std::istreambuf_iterator<char>(json)), std::istreambuf_iterator<char>());
  EXPECT_NE(text.find("\"psnr\""), std::string::npos);
  EXPECT_NE(text.find("\"ssim\""), std::string::npos);
  EXPECT_TRUE(fs::is_regular_file(dir / "ev" / "compare" / "029.png"));
  // --lod on a model of one page: the same figures, and what each view drew.
  const auto lod = run_hisnegs(
      {"eval", "--model", dir / "m.ply", "--data", dir / "gt", "-o", dir / "lod", "--backend", "cpu", "--lod", "1"});
  ASSERT_EQ(lod.exit_code, 0) << lod.err;
  EXPECT_EQ(testing::read_bytes(dir / "lod" / "metrics.csv"), testing::read_bytes(dir / "ev" / "metrics.csv"));
  EXPECT_NE(lod.out.find("eval: level of detail at 1 px: 1 nodes"), std::string::npos) << lod.out;
  const auto bad = run_hisnegs({"eval", "--model", dir / "m.ply", "--data", dir / "nowhere", "-o", dir / "ev2"});
  EXPECT_EQ(bad.exit_code, 2) << bad.err;
  EXPECT_FALSE(fs::exists(dir / "ev2"));
}

TEST(CliTrain, WritesRunFolderResumesAndRejectsBadInput) {
  testing::ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(make_model_and_ground_truth(dir.path(), 24, "both"));
  testing::write_text(dir / "t.yaml", "train:\n  save_every: 2\n  lambda_ssim: 0.2\n");
  auto r = run_hisnegs({"--config", dir / "t.yaml", "train", "--init", dir / "m.ply", "--data", dir / "gt", "-o",
                        dir / "run", "--epochs", "2", "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("epoch 2/2"), std::string::npos) << r.out;
  EXPECT_EQ(csv_rows(dir / "run" / "log.csv"), 2);
  EXPECT_TRUE(fs::is_regular_file(dir / "run" / "final.ply"));
  EXPECT_TRUE(fs::is_regular_file(dir / "run" / "training_curve.png"));
  // The same folder again without --resume is refused; with it, training goes on to epoch 4.
  r = run_hisnegs({"--config", dir / "t.yaml", "train", "--init", dir / "m.ply", "--data", dir / "gt", "-o",
                   dir / "run", "--epochs", "4", "--backend", "cpu"});
  EXPECT_EQ(r.exit_code, 2) << r.err;
  r = run_hisnegs({"--config", dir / "t.yaml", "train", "--init", dir / "m.ply", "--data", dir / "gt", "-o",
                   dir / "run", "--epochs", "4", "--backend", "cpu", "--resume"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(csv_rows(dir / "run" / "log.csv"), 4);
  // Missing ground truth: one line naming what is missing, no run folder.
  r = run_hisnegs(
      {"train", "--init", dir / "m.ply", "--data", dir / "nowhere", "-o", dir / "run2", "--backend", "cpu"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("nowhere"), std::string::npos) << r.err;
  EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  EXPECT_FALSE(fs::exists(dir / "run2"));
}

// Issue 32, item 14: `--data` takes a folder of any `gt --orbit` choice: one set
// (cameras.json + mips.tif in the folder itself) as well as train/ and eval/, and
// the first line says which views it trains on (before: "G/train/cameras.json: no
// such file" for `gt --orbit train -o G`).
TEST(CliTrain, DataIsAnyGroundTruthFolderAndNamesItsViews) {
  testing::ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(make_model_and_ground_truth(dir.path(), 16, "train"));
  ASSERT_TRUE(fs::is_regular_file(dir / "gt" / "cameras.json"));
  auto r = run_hisnegs({"train", "--init", dir / "m.ply", "--data", dir / "gt", "-o", dir / "run", "--epochs", "1",
                        "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("train: 106 views of 16x16 from " + (dir / "gt").string() + " (gt set 'train')"),
            std::string::npos)
      << r.out;
  EXPECT_TRUE(fs::is_regular_file(dir / "run" / "final.ply"));
  // A custom orbit's folder trains too, and says it is the custom set.
  ASSERT_EQ(run_hisnegs({"-q", "gt", dir / "s.tif", "-o", dir / "gc", "--elevations", "0,30", "--ring-views", "4",
                         "--size", "16", "--backend", "cpu"})
                .exit_code,
            0);
  r = run_hisnegs({"train", "--init", dir / "m.ply", "--data", dir / "gc", "-o", dir / "run2", "--epochs", "1",
                   "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("8 views of 16x16 from " + (dir / "gc").string() + " (gt set 'custom')"), std::string::npos)
      << r.out;
  // A folder holding neither: one line naming both places looked at.
  fs::create_directories(dir / "empty");
  r = run_hisnegs({"train", "--init", dir / "m.ply", "--data", dir / "empty", "-o", dir / "run3", "--backend", "cpu"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("empty: no ground truth here: expected " + (dir / "empty" / "train" / "cameras.json").string()),
            std::string::npos)
      << r.err;
  EXPECT_EQ(testing::count_lines(r.err), 1) << r.err;
}

// Training that makes the training views worse (a step 300x the report's) leaves
// the initial model as final.ply, tagged and said; keep_better_init: false keeps
// the trained one.
TEST(CliTrain, KeepsTheInitialModelWhenTrainingMakesTheViewsWorse) {
  testing::ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(make_model_and_ground_truth(dir.path(), 24, "both"));
  const gmf::Checkpoint init = gmf::load_checkpoint((dir / "m.ply").string());
  testing::write_text(dir / "wild.yaml", "train:\n  lr_initial: 1\n  lr_final: 1\n  save_every: 2\n");
  auto r = run_hisnegs({"--config", dir / "wild.yaml", "train", "--init", dir / "m.ply", "--data", dir / "gt", "-o",
                        dir / "run", "--epochs", "2", "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("training made them worse, so final.ply is the initial model"), std::string::npos) << r.out;
  const gmf::Checkpoint kept = gmf::load_checkpoint((dir / "run" / "final.ply").string());
  ASSERT_EQ(kept.mixture.size(), init.mixture.size());
  for (std::size_t k = 0; k < init.mixture.size(); ++k) {
    EXPECT_EQ(gmf::to_array(kept.mixture[k]), gmf::to_array(init.mixture[k])) << k;
  }
  EXPECT_NE(std::find(kept.meta.extra.begin(), kept.meta.extra.end(),
                      std::pair<std::string, std::string>{"train_kept", "init"}),
            kept.meta.extra.end());
  testing::write_text(dir / "wild_keep.yaml",
                      "train:\n  lr_initial: 1\n  lr_final: 1\n  save_every: 2\n  keep_better_init: false\n");
  r = run_hisnegs({"--config", dir / "wild_keep.yaml", "train", "--init", dir / "m.ply", "--data", dir / "gt", "-o",
                   dir / "run2", "--epochs", "2", "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.out.find("training made them worse"), std::string::npos) << r.out;
  const gmf::Checkpoint trained = gmf::load_checkpoint((dir / "run2" / "final.ply").string());
  bool moved = trained.mixture.size() != init.mixture.size();
  for (std::size_t k = 0; !moved && k < init.mixture.size(); ++k) {
    moved = gmf::to_array(trained.mixture[k]) != gmf::to_array(init.mixture[k]);
  }
  EXPECT_TRUE(moved);
  EXPECT_EQ(std::find_if(trained.meta.extra.begin(), trained.meta.extra.end(),
                         [](const auto& kv) { return kv.first == "train_kept"; }),
            trained.meta.extra.end());
}

TEST(CliRender, BadInputsGetOneLineErrors) {
  testing::ScratchDir dir;
  testing::write_text(dir / "not.ply", "ply\nformat ascii 1.0\nelement face 0\nend_header\n");
  auto r = run_hisnegs({"render", "--model", dir / "not.ply", "--orbit", "4", "-o", dir / "r", "--backend", "cpu"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("not.ply"), std::string::npos) << r.err;
  r = run_hisnegs({"render", "--model", dir / "missing.ply", "-o", dir / "r"});
  EXPECT_EQ(r.exit_code, 2);
  r = run_hisnegs({"render", "--model", dir / "not.ply", "-o", dir / "r", "--beta", "-1", "--orbit", "3"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("splat.beta"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "r"));
}

TEST(CliBench, RenderSuiteRunsWithTinySizes) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,32,32"}).exit_code, 0);
  const auto r = run_hisnegs({"bench", "render", "--volume", dir / "s.tif", "--sizes", "32", "--gaussians", "300",
                              "--betas", "5", "--benchmark_filter=cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("render/cpu/soft_backward/K50000/32"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("render/cpu/hard/K300/256"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("gt/cpu/exact"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("median_ms"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace hisnegs
