// SPDX-License-Identifier: Apache-2.0
// End-to-end runs of the hisnegs executable: help, synth -> info -> vdb -> info,
// config dump and the io benchmark suite on a tiny stack.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "tests/test_support.hpp"

namespace hisnegs {
namespace {
namespace fs = std::filesystem;
using testing::run_hisnegs;

TEST(Cli, HelpListsCommandsAndExitsZero) {
  const auto r = run_hisnegs({"--help"});
  EXPECT_EQ(r.exit_code, 0);
  for (const char* c : {"demo", "synth", "info", "vdb", "config", "bench"}) {
    EXPECT_NE(r.out.find(c), std::string::npos) << c;
  }
  EXPECT_EQ(run_hisnegs({}).exit_code, 2);  // a subcommand is required
}

TEST(Cli, SynthInfoVdbChain) {
  testing::ScratchDir dir;
  const auto tif = dir / "s.tif";
  auto r = run_hisnegs({"synth", "-o", tif, "--seed", "3", "--shape", "24,64,80"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = run_hisnegs({"info", tif});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("Z=24 Y=64 X=80"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("uint16"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("ImageJ"), std::string::npos) << r.out;  // spacing came from the file
  EXPECT_NE(r.out.find("foreground"), std::string::npos) << r.out;

  r = run_hisnegs({"vdb", tif, "-o", dir / "s.vdb", "--band", "1"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = run_hisnegs({"info", dir / "s.vdb"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("grid 'volume'"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("band_voxels"), std::string::npos) << r.out;
}

TEST(Cli, SameSeedSameFile) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "a.tif", "--shape", "16,40,40"}).exit_code, 0);
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "b.tif", "--shape", "16,40,40"}).exit_code, 0);
  std::ifstream a(dir / "a.tif", std::ios::binary), b(dir / "b.tif", std::ios::binary);
  const std::string sa((std::istreambuf_iterator<char>(a)), {}), sb((std::istreambuf_iterator<char>(b)), {});
  EXPECT_EQ(sa, sb);
}

TEST(Cli, ConfigDumpReloads) {
  testing::ScratchDir dir;
  const auto r = run_hisnegs({"config"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  testing::write_text(dir / "dump.yaml", r.out);
  const auto again = run_hisnegs({"--config", dir / "dump.yaml", "config"});
  ASSERT_EQ(again.exit_code, 0) << again.err;
  EXPECT_EQ(again.out, r.out);
}

TEST(Cli, IoBenchmarkSuiteRuns) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,32,32"}).exit_code, 0);
  const auto r = run_hisnegs({"bench", "io", "--volume", dir / "s.tif", "--benchmark_min_time=0.01"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("io/load_and_normalize/s.tif"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("io/build_sparse_grid/s.tif"), std::string::npos) << r.out;
}

TEST(Cli, GmfBenchmarkSuiteRuns) {
  const auto r = run_hisnegs({"bench", "gmf", "--benchmark_min_time=0.01"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* name :
       {"gmf/residual_block/analytic", "gmf/residual_block/numeric_central", "gmf/residual_block/autodiff"}) {
    EXPECT_NE(r.out.find(name), std::string::npos) << r.out;
  }
}

TEST(Cli, GtBenchmarkSuiteRuns) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,32,32"}).exit_code, 0);
  const auto r = run_hisnegs({"bench", "gt", "--volume", dir / "s.tif", "--sizes", "16"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("gt/cpu/exact/s.tif/16"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("median_ms_per_view"), std::string::npos) << r.out;
}

}  // namespace
}  // namespace hisnegs

namespace hisnegs {
namespace {

TEST(CliGt, WritesCamerasStackPreviewsAndMeta) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,48,48"}).exit_code, 0);
  auto r = run_hisnegs({"gt", dir / "s.tif", "-o", dir / "gt", "--size", "32", "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const char* set : {"train", "eval"}) {
    const fs::path d = dir / "gt" / set;
    EXPECT_TRUE(fs::exists(d / "cameras.json")) << set;
    EXPECT_TRUE(fs::exists(d / "mips.tif")) << set;
    EXPECT_TRUE(fs::exists(d / "meta.json")) << set;
  }
  EXPECT_TRUE(fs::exists(dir / "gt" / "train" / "previews" / "105.png"));
  EXPECT_TRUE(fs::exists(dir / "gt" / "eval" / "previews" / "029.png"));
  r = run_hisnegs({"info", dir / "gt" / "eval" / "mips.tif"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("Z=30 Y=32 X=32"), std::string::npos) << r.out;
  // Re-render the eval views from the written cameras file: identical stack.
  r = run_hisnegs({"-q", "gt", dir / "s.tif", "-o", dir / "again", "--cameras", dir / "gt" / "eval" / "cameras.json",
                   "--backend", "cpu"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::ifstream a(dir / "gt" / "eval" / "mips.tif", std::ios::binary), b(dir / "again" / "mips.tif", std::ios::binary);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(a), {}), std::string(std::istreambuf_iterator<char>(b), {}));
}

TEST(CliGt, CustomOrbitAndBadInputs) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,48,48"}).exit_code, 0);
  auto r = run_hisnegs({"-q", "gt", dir / "s.tif", "-o", dir / "c", "--elevations", "-90,0,90", "--ring-views", "4",
                        "--size", "16", "--mode", "report"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir / "c" / "previews" / "011.png"));
  testing::write_text(dir / "bad.json", R"({"width": 8, "height": 8, "fx": 8, "fy": 8, "cx": 4, "cy": 4,
    "near": 0.01, "far": 10, "views": [{"name": "a", "R": [[1,0,0],[0,1,0],[0,0,2]], "T": [0,0,2.5]}]})");
  r = run_hisnegs({"gt", dir / "s.tif", "-o", dir / "bad", "--cameras", dir / "bad.json"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("views[0].R: not a rotation"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "bad" / "mips.tif"));
  r = run_hisnegs({"gt", dir / "s.tif", "-o", dir / "bad", "--mode", "fast"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--mode"), std::string::npos) << r.err;
  r = run_hisnegs({"gt", dir / "s.tif", "-o", dir / "bad", "--size", "2"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("camera.width = 2"), std::string::npos) << r.err;
  EXPECT_EQ(testing::count_lines(r.err), 1) << r.err;
}

}  // namespace
}  // namespace hisnegs

namespace hisnegs {
namespace {

TEST(CliFit, WritesCheckpointAndCsvLog) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,48,48"}).exit_code, 0);
  testing::write_text(dir / "c.yaml", "gmf:\n  rounds: 2\n  iterations_per_round: 3\n");
  auto r = run_hisnegs({"--config", dir / "c.yaml", "fit", dir / "s.tif", "-o", dir / "m.ply", "--gaussians", "150",
                        "--time-budget", "60", "--log", dir / "fit.csv"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("3D PSNR"), std::string::npos) << r.out;
  // The objective and where its samples sit, with sample_jitter's automatic value.
  EXPECT_NE(r.out.find("fit: softmax (beta 8 -> 64), the last 25% on the max objective; samples moved within their "
                       "voxels each round (gmf.sample_jitter auto for the softmax: 1)"),
            std::string::npos)
      << r.out;
  auto sum = run_hisnegs({"--config", dir / "c.yaml", "fit", dir / "s.tif", "-o", dir / "sum.ply", "--gaussians", "150",
                          "--aggregation", "sum"});
  ASSERT_EQ(sum.exit_code, 0) << sum.err;
  EXPECT_NE(sum.out.find("fit: sum (report Eq. 1) objective; samples at the voxel centres (gmf.sample_jitter auto for "
                         "the sum: 0)"),
            std::string::npos)
      << sum.out;
  r = run_hisnegs({"info", dir / "m.ply"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("volume       Z=16 Y=48 X=48"), std::string::npos) << r.out;
  EXPECT_EQ(r.out.find("halos"), std::string::npos) << "without --volume there is no stack to compare with";
  // Against its stack: the halo count (gmf/core/halo.hpp); --volume with a stack, or
  // a stack of another shape, is one line naming the file.
  r = run_hisnegs({"info", dir / "m.ply", "--volume", dir / "s.tif"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("% of K) with a peak above the stack at their centre by more than its noise (0.02)"),
            std::string::npos)
      << r.out;
  r = run_hisnegs({"info", dir / "s.tif", "--volume", dir / "s.tif"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("is not a checkpoint: --volume"), std::string::npos) << r.err;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "other.tif", "--shape", "16,40,48"}).exit_code, 0);
  r = run_hisnegs({"info", dir / "m.ply", "--volume", dir / "other.tif"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("the model was fitted to a 48x48x16 stack"), std::string::npos) << r.err;
  std::ifstream csv(dir / "fit.csv");
  std::string header;
  std::getline(csv, header);
  EXPECT_EQ(header, "iteration,seconds,loss,psnr_fg,psnr_3d,gaussians,round,beta");
  int rows = 0;
  for (std::string line; std::getline(csv, line);) ++rows;
  EXPECT_GE(rows, 3);
  r = run_hisnegs({"fit", dir / "s.tif", "-o", dir / "x.ply", "--optimizer", "newton"});
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("--optimizer = 'newton'"), std::string::npos) << r.err;
  EXPECT_FALSE(fs::exists(dir / "x.ply"));
}

}  // namespace
}  // namespace hisnegs
