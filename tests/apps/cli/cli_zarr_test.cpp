// SPDX-License-Identifier: Apache-2.0
// OME-Zarr stacks through the real binary: `info` prints the pyramid, `gt` and
// `fit` (in memory and in bricks) read an OME-Zarr copy of a TIFF stack to the same
// result, `export volume` writes a pyramid `info` reads, an output inside an input
// store is refused, and bad Zarr input is one line naming the file, exit 2,
// nothing written.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <vector>

#include "io/tiff_stack.hpp"
#include "io/zarr_stack.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {
namespace fs = std::filesystem;
using testing::run_hisnegs;

// s.tif (synthetic, uint16) and s.ome.zarr, its copy as a two-level pyramid.
void make_stacks(const testing::ScratchDir& dir) {
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,80,96"}).exit_code, 0);
  const io::Volume v = io::read_tiff_stack(dir / "s.tif");
  io::ZarrWriteOptions o;
  o.type = v.stored_as;
  o.chunk_edge = 32;
  o.min_edge = 40;
  io::write_ome_zarr(dir / "s.ome.zarr", v, o);
}

std::string without_source(std::string t) {
  const auto at = t.find("comment hisnegs source ");
  if (at != std::string::npos) t.erase(at, t.find('\n', at) - at);
  return t;
}

TEST(CliZarr, EveryStackCommandReadsAnOmeZarrCopy) {
  testing::ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(make_stacks(dir));
  const auto info = run_hisnegs({"info", dir / "s.ome.zarr"});
  ASSERT_EQ(info.exit_code, 0) << info.err;
  EXPECT_NE(info.out.find("OME-Zarr v0.4 (Zarr v2), level 0 of 2, uint16, axes zyx, chunks 16x32x32, blosc(zstd)"),
            std::string::npos) << info.out;
  EXPECT_NE(info.out.find("level 1 (1): zyx 16x40x48"), std::string::npos) << info.out;
  EXPECT_NE(info.out.find("OME-Zarr scale"), std::string::npos) << info.out;
  // Ground truth from either stack is the same image, byte for byte.
  ASSERT_EQ(run_hisnegs({"-q", "gt", dir / "s.tif", "-o", dir / "gt_tif", "--orbit", "eval", "--size", "48"}).exit_code, 0);
  const auto gt = run_hisnegs({"-q", "gt", dir / "s.ome.zarr", "-o", dir / "gt_zarr", "--orbit", "eval", "--size", "48"});
  ASSERT_EQ(gt.exit_code, 0) << gt.err;
  EXPECT_EQ(testing::read_bytes(dir / "gt_zarr" / "mips.tif"), testing::read_bytes(dir / "gt_tif" / "mips.tif"));
  const auto bricked = run_hisnegs({"-q", "gt", dir / "s.ome.zarr", "-o", dir / "gt_bricks", "--orbit", "eval", "--size",
                                    "48", "--brick-voxels", "32"});
  ASSERT_EQ(bricked.exit_code, 0) << bricked.err;
  EXPECT_EQ(testing::read_bytes(dir / "gt_bricks" / "mips.tif"), testing::read_bytes(dir / "gt_tif" / "mips.tif"));
  // A fixed-schedule fit, in memory and in bricks: the same checkpoint but for the source line.
  testing::write_text(dir / "fixed.yaml", "gmf: {gaussians: 40, rounds: 2, iterations_per_round: 5, time_budget_s: 0}\n");
  for (const bool bricks : {false, true}) {
    SCOPED_TRACE(bricks ? "bricks" : "in memory");
    auto fit = [&](const fs::path& in, const fs::path& out) {
      std::vector<std::string> args{"-q", "--config", (dir / "fixed.yaml").string(), "fit", in.string(), "-o", out.string()};
      if (bricks) args.insert(args.end(), {"--brick-voxels", "48"});
      return run_hisnegs(args);
    };
    const auto a = fit(dir / "s.tif", dir / "a.ply");
    ASSERT_EQ(a.exit_code, 0) << a.err;
    const auto b = fit(dir / "s.ome.zarr", dir / "b.ply");
    ASSERT_EQ(b.exit_code, 0) << b.err;
    EXPECT_EQ(without_source(testing::read_bytes(dir / "a.ply")), without_source(testing::read_bytes(dir / "b.ply")));
  }
  // --level 1: the coarser level, with its own voxel size.
  const auto coarse = run_hisnegs({"info", dir / "s.ome.zarr", "--level", "1"});
  ASSERT_EQ(coarse.exit_code, 0) << coarse.err;
  EXPECT_NE(coarse.out.find("shape        Z=16 Y=40 X=48"), std::string::npos) << coarse.out;
  // export volume writes a pyramid that reads back; an output inside an input store is refused.
  const auto exported = run_hisnegs({"-q", "export", "volume", "--model", dir / "b.ply", "-o", dir / "m.ome.zarr"});
  ASSERT_EQ(exported.exit_code, 0) << exported.err;
  EXPECT_EQ(run_hisnegs({"info", dir / "m.ome.zarr"}).exit_code, 0);
  const auto inside = run_hisnegs({"fit", dir / "s.ome.zarr", "-o", dir / "s.ome.zarr" / "m.ply"});
  EXPECT_EQ(inside.exit_code, 2);
  EXPECT_NE(inside.err.find("is also an input"), std::string::npos) << inside.err;
  EXPECT_FALSE(fs::exists(dir / "s.ome.zarr" / "m.ply"));
  const auto over = run_hisnegs({"export", "volume", "--model", dir / "b.ply", "-o", dir / "s.ome.zarr", "--match-volume",
                                 dir / "s.ome.zarr"});
  EXPECT_EQ(over.exit_code, 2);
  EXPECT_NE(over.err.find("is also an input"), std::string::npos) << over.err;
}

// `run` on an OME-Zarr stack: every stage, then a second run reuses them all (the
// folder's identity is stable); a run folder inside the store is refused.
TEST(CliZarr, RunTakesAnOmeZarrStackAndResumesOnItsIdentity) {
  testing::ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(make_stacks(dir));
  testing::write_text(dir / "tiny.yaml",
                      "camera: {width: 32, height: 32}\n"
                      "gmf: {optimizer: adam, gaussians: 150, time_budget_s: 0, rounds: 2, iterations_per_round: 10}\n"
                      "train: {epochs: 2, beta_warmup_epochs: 1, densify_from: 2, densify_every: 2, densify_until: 2, "
                      "prune_every: 2, save_every: 1}\n");
  const auto run = [&] {
    return run_hisnegs({"--config", dir / "tiny.yaml", "run", dir / "s.ome.zarr", "-o", dir / "R", "--orbit-frames", "4"});
  };
  const auto first = run();
  ASSERT_EQ(first.exit_code, 0) << first.err;
  EXPECT_TRUE(fs::exists(dir / "R" / "report.md"));
  const auto again = run();
  ASSERT_EQ(again.exit_code, 0) << again.err;
  EXPECT_NE(again.out.find("[1/"), std::string::npos);
  EXPECT_NE(again.out.find(": reused ("), std::string::npos) << again.out;
  const auto inside = run_hisnegs({"--config", dir / "tiny.yaml", "run", dir / "s.ome.zarr", "-o", dir / "s.ome.zarr" / "R"});
  EXPECT_EQ(inside.exit_code, 2);
  EXPECT_NE(inside.err.find("is also an input"), std::string::npos) << inside.err;
  EXPECT_FALSE(fs::exists(dir / "s.ome.zarr" / "R"));
}

TEST(CliZarr, BadZarrInputIsOneLineExitTwoAndWritesNothing) {
  testing::ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(make_stacks(dir));
  const fs::path chunk = dir / "s.ome.zarr" / "0" / "0" / "1" / "1";
  const std::vector<std::pair<std::function<void()>, std::string>> cases{
      {[&] { std::ofstream(chunk, std::ios::binary | std::ios::trunc) << "garbage"; }, chunk.string() + ": blosc: "},
      {[&] { std::ofstream(dir / "s.ome.zarr" / "0" / ".zarray", std::ios::trunc) << "{\"zarr_format\": 2"; },
       (dir / "s.ome.zarr" / "0" / ".zarray").string() + ": is not valid JSON"},
      {[&] { fs::remove(dir / "s.ome.zarr" / "0" / ".zarray"); }, (dir / "s.ome.zarr" / "0").string() + ": holds no Zarr array"},
  };
  for (const auto& [damage, expect] : cases) {
    damage();
    for (const std::vector<std::string>& command :
         {std::vector<std::string>{"fit", dir / "s.ome.zarr", "-o", dir / "m.ply"},
          std::vector<std::string>{"gt", dir / "s.ome.zarr", "-o", dir / "g", "--orbit", "eval", "--size", "32"}}) {
      const auto r = run_hisnegs(command);
      EXPECT_EQ(r.exit_code, 2) << command[0] << ": " << r.err;
      EXPECT_NE(r.err.find(expect), std::string::npos) << command[0] << ": " << r.err;
      const std::string error_line = r.err.substr(std::min(r.err.size(), r.err.find("hisnegs: error: ")));  // after the back end's notice
      EXPECT_EQ(std::count(error_line.begin(), error_line.end(), '\n'), 1) << r.err;
    }
    EXPECT_FALSE(fs::exists(dir / "m.ply"));
    EXPECT_FALSE(fs::exists(dir / "g"));
  }
  const auto level = run_hisnegs({"fit", dir / "s.tif", "-o", dir / "m.ply", "--level", "1"});
  EXPECT_EQ(level.exit_code, 2);
  EXPECT_NE(level.err.find("--level is for OME-Zarr stacks"), std::string::npos) << level.err;
}

double psnr_said(const std::string& out) {
  const auto at = out.find("3D PSNR ");
  return at == std::string::npos ? -1.0 : std::stod(out.substr(at + 8));
}

// `fit --init`: a fit of level 0 starts from a fit of level 1 (the same world box),
// in memory and in bricks, and with the same short schedule ends closer to the stack
// than a fit from gmf.init; a model of another box is refused in one line, exit 2,
// nothing written; the brick folder's fingerprint names the start.
TEST(CliZarr, AFitStartsFromACoarserLevelsFit) {
  testing::ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(make_stacks(dir));
  testing::write_text(dir / "short.yaml", "gmf: {gaussians: 60, rounds: 2, iterations_per_round: 10, time_budget_s: 0}\n");
  const auto fit = [&](std::vector<std::string> more) {
    std::vector<std::string> args{"--config", (dir / "short.yaml").string(), "fit", (dir / "s.ome.zarr").string()};
    args.insert(args.end(), more.begin(), more.end());
    return run_hisnegs(args);
  };
  const auto coarse = fit({"--level", "1", "-o", (dir / "l1.ply").string()});
  ASSERT_EQ(coarse.exit_code, 0) << coarse.err;
  const auto cold = fit({"-o", (dir / "cold.ply").string()});
  ASSERT_EQ(cold.exit_code, 0) << cold.err;
  const auto warm = fit({"--init", (dir / "l1.ply").string(), "-o", (dir / "warm.ply").string()});
  ASSERT_EQ(warm.exit_code, 0) << warm.err;
  EXPECT_NE(warm.out.find("Gaussians from " + (dir / "l1.ply").string()), std::string::npos) << warm.out;
  EXPECT_NE(warm.out.find("beta 64 -> 64"), std::string::npos) << warm.out;
  EXPECT_GT(psnr_said(warm.out), psnr_said(cold.out)) << warm.out << cold.out;
  const auto bricks = fit({"--init", (dir / "l1.ply").string(), "-o", (dir / "wb.ply").string(), "--brick-voxels", "48"});
  ASSERT_EQ(bricks.exit_code, 0) << bricks.err;
  EXPECT_NE(bricks.out.find("each brick starts from the Gaussians of"), std::string::npos) << bricks.out;
  EXPECT_GT(psnr_said(bricks.out), 0.0) << bricks.out;
  // A model of another stack's box.
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "other.tif", "--shape", "16,80,40"}).exit_code, 0);
  const auto other = run_hisnegs({"-q", "--config", dir / "short.yaml", "fit", dir / "other.tif", "-o", dir / "o.ply"});
  ASSERT_EQ(other.exit_code, 0) << other.err;
  const auto refused = fit({"--init", (dir / "o.ply").string(), "-o", (dir / "x.ply").string()});
  EXPECT_EQ(refused.exit_code, 2);
  EXPECT_EQ(testing::count_lines(refused.err), 1) << refused.err;
  EXPECT_NE(refused.err.find("o.ply: is a model of the world box"), std::string::npos) << refused.err;
  EXPECT_FALSE(fs::exists(dir / "x.ply"));
  // The start is an input: never the output.
  const auto over = fit({"--init", (dir / "l1.ply").string(), "-o", (dir / "l1.ply").string()});
  EXPECT_EQ(over.exit_code, 2);
  EXPECT_NE(over.err.find("is also an input (--init)"), std::string::npos) << over.err;
}

}  // namespace
}  // namespace hisnegs
