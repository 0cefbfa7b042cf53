// SPDX-License-Identifier: Apache-2.0
// HDF5 stacks through the real binary: `info` names the layout it found, `gt` and
// `fit` read an HDF5 copy of a TIFF stack to the same result, and bad HDF5 input
// (a truncated file, a dataset that does not exist, --dataset on a TIFF) is one
// line naming the file, exit 2, nothing written.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include "io/hdf5_stack.hpp"
#include "io/tiff_stack.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {
namespace fs = std::filesystem;
using testing::run_hisnegs;

TEST(CliHdf5, EveryStackCommandReadsAnHdf5Copy) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,40,48"}).exit_code, 0);
  const io::Volume v = io::read_tiff_stack(dir / "s.tif");
  io::write_hdf5_stack(dir / "s.h5", v, {.dataset = "/volume/raw", .type = v.stored_as, .chunk_zyx = {8, 16, 16}});
  const auto info = run_hisnegs({"info", dir / "s.h5"});
  ASSERT_EQ(info.exit_code, 0) << info.err;
  EXPECT_NE(info.out.find("HDF5, volume/raw 16x40x48, uint16, chunks 8x16x16, gzip"), std::string::npos) << info.out;
  EXPECT_NE(info.out.find("HDF5 metadata"), std::string::npos) << info.out;
  // Ground truth from either file is the same image, byte for byte.
  ASSERT_EQ(run_hisnegs({"-q", "gt", dir / "s.tif", "-o", dir / "gt_tif", "--orbit", "eval", "--size", "48"}).exit_code, 0);
  const auto gt = run_hisnegs({"-q", "gt", dir / "s.h5", "-o", dir / "gt_h5", "--orbit", "eval", "--size", "48"});
  ASSERT_EQ(gt.exit_code, 0) << gt.err;
  EXPECT_EQ(testing::read_bytes(dir / "gt_h5" / "mips.tif"), testing::read_bytes(dir / "gt_tif" / "mips.tif"));
  // A fixed-schedule fit of either file: the same checkpoint but for the source line.
  testing::write_text(dir / "fixed.yaml", "gmf: {gaussians: 40, rounds: 2, iterations_per_round: 5, time_budget_s: 600}\n");
  auto fit = [&](const fs::path& in, const fs::path& out) {
    return run_hisnegs({"-q", "--config", (dir / "fixed.yaml").string(), "fit", in.string(), "-o", out.string()});
  };
  const auto a = fit(dir / "s.tif", dir / "a.ply");
  ASSERT_EQ(a.exit_code, 0) << a.err;
  const auto b = fit(dir / "s.h5", dir / "b.ply");
  ASSERT_EQ(b.exit_code, 0) << b.err;
  std::string ta = testing::read_bytes(dir / "a.ply"), tb = testing::read_bytes(dir / "b.ply");
  const auto strip_source = [](std::string& t) {
    const auto at = t.find("comment hisnegs source ");
    if (at != std::string::npos) t.erase(at, t.find('\n', at) - at);
  };
  strip_source(ta);
  strip_source(tb);
  EXPECT_EQ(ta, tb);
}

TEST(CliHdf5, BadHdf5InputIsOneLineAndWritesNothing) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,40,48"}).exit_code, 0);
  const io::Volume v = io::read_tiff_stack(dir / "s.tif");
  io::write_hdf5_stack(dir / "s.h5", v, {.type = v.stored_as});
  const auto missing = run_hisnegs({"gt", dir / "s.h5", "-o", dir / "g1", "--dataset", "/nope"});
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_NE(missing.err.find((dir / "s.h5").string() + ": has no dataset /nope"), std::string::npos) << missing.err;
  EXPECT_FALSE(fs::exists(dir / "g1"));
  const auto on_tiff = run_hisnegs({"fit", dir / "s.tif", "-o", dir / "m.ply", "--dataset", "/data"});
  EXPECT_EQ(on_tiff.exit_code, 2);
  EXPECT_NE(on_tiff.err.find("--dataset is for HDF5 files"), std::string::npos) << on_tiff.err;
  EXPECT_FALSE(fs::exists(dir / "m.ply"));
  for (const char* flag : {"--channel", "--timepoint"}) {  // a negative index: said so, not "choose one"
    const auto negative = run_hisnegs({"gt", dir / "s.h5", "-o", dir / "g2", flag, "-1"});
    EXPECT_EQ(negative.exit_code, 2);
    EXPECT_NE(negative.err.find(std::string(flag) + ": Value -1 not in range"), std::string::npos) << negative.err;
    EXPECT_FALSE(fs::exists(dir / "g2"));
  }
  fs::resize_file(dir / "s.h5", fs::file_size(dir / "s.h5") / 2);
  const auto truncated = run_hisnegs({"vdb", dir / "s.h5", "-o", dir / "s.vdb"});
  EXPECT_EQ(truncated.exit_code, 2);
  EXPECT_NE(truncated.err.find((dir / "s.h5").string() + ": "), std::string::npos) << truncated.err;
  EXPECT_EQ(std::count(truncated.err.begin(), truncated.err.end(), '\n'), 1) << truncated.err;
  EXPECT_FALSE(fs::exists(dir / "s.vdb"));
}

// The .h5 a BigDataViewer .xml names is an input as much as the .xml: no command
// writes over it (nor over the .xml beside an .h5 it reads), and nothing is written.
TEST(CliHdf5, FilesBehindABigDataViewerXmlAreInputsToo) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,40,48"}).exit_code, 0);
  io::write_hdf5_stack(dir / "g.h5", io::read_tiff_stack(dir / "s.tif"), {});
  testing::write_text(dir / "g.xml",
                      "<?xml version=\"1.0\"?><SpimData version=\"0.2\"><SequenceDescription>"
                      "<ImageLoader format=\"bdv.hdf5\"><hdf5 type=\"relative\">g.h5</hdf5></ImageLoader>"
                      "<ViewSetups><ViewSetup><id>0</id></ViewSetup></ViewSetups></SequenceDescription></SpimData>");
  testing::write_text(dir / "fixed.yaml", "gmf: {gaussians: 20, rounds: 1, iterations_per_round: 2}\n");
  ASSERT_EQ(run_hisnegs({"-q", "--config", dir / "fixed.yaml", "fit", dir / "s.tif", "-o", dir / "m.ply"}).exit_code,
            0);
  const std::string h5 = testing::read_bytes(dir / "g.h5"), xml = testing::read_bytes(dir / "g.xml");
  const std::vector<std::vector<std::string>> commands = {
      {"fit", dir / "g.xml", "-o", dir / "g.h5"},
      {"vdb", dir / "g.xml", "-o", dir / "g.h5"},
      {"vdb", dir / "g.h5", "-o", dir / "g.xml"},
      {"export", "volume", "--model", dir / "m.ply", "--match-volume", dir / "g.xml", "-o", dir / "g.h5"},
  };
  for (const auto& args : commands) {
    const auto r = run_hisnegs(args);
    EXPECT_EQ(r.exit_code, 2) << args[0] << " " << args[1];
    EXPECT_NE(r.err.find("is also an input"), std::string::npos) << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << r.err;
  }
  EXPECT_EQ(testing::read_bytes(dir / "g.h5"), h5);
  EXPECT_EQ(testing::read_bytes(dir / "g.xml"), xml);
}

}  // namespace
}  // namespace hisnegs
