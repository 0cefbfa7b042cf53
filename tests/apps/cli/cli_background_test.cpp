// SPDX-License-Identifier: Apache-2.0
// Issue 33 through the real binary: raw-like test data (`noise`, `synth --noise
// raw`), a fit that records the stack's background, renders that draw its floor
// (and `--background none` that do not), and stacks whose background was
// subtracted, which record none.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <string>

#include "gmf/core/checkpoint.hpp"
#include "io/tiff_stack.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {
namespace fs = std::filesystem;
using testing::run_hisnegs;

TEST(CliNoise, AddsDetectorNoiseDeterministicallyAndSaysWhatTheBackgroundBecame) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "16,40,40"}).exit_code, 0);
  const auto r = run_hisnegs({"noise", dir / "s.tif", "-o", dir / "n.tif", "--background-photons", "3", "--seed", "5"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("noise: wrote"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("Poisson(3 photons)"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("% zeros, mean"), std::string::npos) << r.out;
  const io::Volume clean = io::read_tiff_stack(dir / "s.tif"), noisy = io::read_tiff_stack(dir / "n.tif");
  EXPECT_EQ(noisy.stored_as, clean.stored_as);
  EXPECT_EQ(noisy.spacing.um, clean.spacing.um);
  ASSERT_EQ(noisy.size(), clean.size());
  double added = 0;
  for (std::size_t i = 0; i < clean.size(); ++i) added += noisy.voxels[i] - clean.voxels[i];
  EXPECT_NEAR(added / static_cast<double>(clean.size()), 3.0, 0.1);  // Poisson(3) counts added on average
  // The same seed gives the same file; another seed another.
  ASSERT_EQ(run_hisnegs({"-q", "noise", dir / "s.tif", "-o", dir / "m.tif", "--background-photons", "3", "--seed", "5"})
                .exit_code,
            0);
  EXPECT_EQ(testing::read_bytes(dir / "m.tif"), testing::read_bytes(dir / "n.tif"));
  // Bad values: one line naming the field, nothing written.
  const auto bad = run_hisnegs({"noise", dir / "s.tif", "-o", dir / "b.tif", "--gain", "0"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("noise.gain = 0: must be in (0, 1000]"), std::string::npos) << bad.err;
  EXPECT_FALSE(fs::exists(dir / "b.tif"));
}

// --estimate measures a stack's noise (the library's recovery is tested in
// apps/simulate/detector_noise_test.cpp): here the synthetic stack with a 5-photon background at
// gain 2 and offset 10 reads back near those, and the flags that make no sense together
// are refused.
TEST(CliNoise, EstimateReportsTheStacksNoise) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "s.tif", "--shape", "24,96,96"}).exit_code, 0);
  ASSERT_EQ(run_hisnegs({"-q", "noise", dir / "s.tif", "-o", dir / "n.tif", "--background-photons", "5", "--gain", "2",
                         "--offset", "10", "--shot-noise"})
                .exit_code,
            0);
  const auto r = run_hisnegs({"noise", dir / "n.tif", "--estimate", "--offset", "10"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("counts/photon, read noise"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("(offset 10 given)"), std::string::npos) << r.out;
  const auto both = run_hisnegs({"noise", dir / "n.tif", "--estimate", "-o", dir / "x.tif"});
  EXPECT_EQ(both.exit_code, 2);
  EXPECT_NE(both.err.find("--estimate writes nothing"), std::string::npos) << both.err;
  EXPECT_FALSE(fs::exists(dir / "x.tif"));
  const auto none = run_hisnegs({"noise", dir / "n.tif"});
  EXPECT_NE(none.exit_code, 0);
  EXPECT_NE(none.err.find("--output"), std::string::npos) << none.err;
}

// A fit records the background of a raw stack (and none of a subtracted one); render
// and eval draw its floor unless told --background none, and say which.
TEST(CliBackground, FitRecordsItAndRendersDrawItsFloor) {
  testing::ScratchDir dir;
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "raw.tif", "--shape", "16,48,48", "--noise", "raw"}).exit_code, 0);
  ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir / "sub.tif", "--shape", "16,48,48"}).exit_code, 0);
  const auto fit = run_hisnegs({"fit", dir / "raw.tif", "-o", dir / "raw.ply", "--gaussians", "60", "--time-budget", "4"});
  ASSERT_EQ(fit.exit_code, 0) << fit.err;
  EXPECT_NE(fit.out.find("fit: background: "), std::string::npos) << fit.out;
  EXPECT_NE(fit.out.find("samples per voxel"), std::string::npos) << fit.out;
  const gmf::Checkpoint raw = gmf::load_checkpoint(dir / "raw.ply");
  EXPECT_FALSE(gmf::background_of(raw.meta, "raw.ply").none());
  const auto sub = run_hisnegs({"fit", dir / "sub.tif", "-o", dir / "sub.ply", "--gaussians", "60", "--time-budget", "4"});
  ASSERT_EQ(sub.exit_code, 0) << sub.err;
  EXPECT_NE(sub.out.find("fit: background: exactly 0"), std::string::npos) << sub.out;
  EXPECT_TRUE(gmf::background_of(gmf::load_checkpoint(dir / "sub.ply").meta, "sub.ply").none());

  const auto info = run_hisnegs({"info", dir / "raw.ply"});
  EXPECT_NE(info.out.find("renders draw its MIP floor"), std::string::npos) << info.out;
  EXPECT_NE(info.out.find("needles"), std::string::npos) << info.out;

  ASSERT_EQ(run_hisnegs({"-q", "gt", dir / "raw.tif", "-o", dir / "gt", "--orbit", "eval", "--size", "24",
                         "--backend", "cpu"})
                .exit_code,
            0);
  for (const char* mode : {"hard", "soft"}) {
    const auto with = run_hisnegs({"render", "--model", dir / "raw.ply", "--cameras", dir / "gt" / "cameras.json",
                                   "-o", dir / (std::string("w") + mode), "--mode", mode, "--backend", "cpu"});
    ASSERT_EQ(with.exit_code, 0) << with.err;
    EXPECT_NE(with.out.find("over the background's floor"), std::string::npos) << with.out;
    const auto without = run_hisnegs({"render", "--model", dir / "raw.ply", "--cameras", dir / "gt" / "cameras.json",
                                      "-o", dir / (std::string("n") + mode), "--mode", mode, "--background", "none",
                                      "--backend", "cpu"});
    ASSERT_EQ(without.exit_code, 0) << without.err;
    EXPECT_EQ(without.out.find("over the background's floor"), std::string::npos) << without.out;
    const io::Volume a = io::read_tiff_stack(dir / (std::string("w") + mode) / "render.tif");
    const io::Volume b = io::read_tiff_stack(dir / (std::string("n") + mode) / "render.tif");
    ASSERT_EQ(a.size(), b.size());
    double raised = 0;
    for (std::size_t i = 0; i < a.size(); ++i) {
      EXPECT_GE(a.voxels[i], b.voxels[i]) << mode << " " << i;  // max(splat, floor)
      raised = std::max(raised, static_cast<double>(a.voxels[i] - b.voxels[i]));
    }
    EXPECT_GT(raised, 0.0) << mode << ": the floor changed nothing";
  }
  const auto bad = run_hisnegs({"render", "--model", dir / "raw.ply", "--cameras", dir / "gt" / "cameras.json", "-o",
                                dir / "x", "--background", "some"});
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_NE(bad.err.find("--background = 'some': expected model or none"), std::string::npos) << bad.err;
}

// Old checkpoints (no background line) read as none and render as before.
TEST(CliBackground, CheckpointsWithoutABackgroundReadAsNone) {
  testing::ScratchDir dir;
  gmf::GaussianMixture m;
  for (int k = 0; k < 3; ++k) {
    gmf::GaussianParams g;
    g.mean = {0.2f * static_cast<float>(k), 0.0f, 0.0f};
    m.push_back(g);
  }
  gmf::CheckpointMeta meta;
  meta.volume_shape_zyx = std::array<int, 3>{8, 16, 16};
  meta.aspect = std::array<double, 3>{1.0, 1.0, 0.5};
  gmf::save_checkpoint(dir / "old.ply", m, meta);
  EXPECT_TRUE(gmf::background_of(gmf::load_checkpoint(dir / "old.ply").meta, "old.ply").none());
  const auto info = run_hisnegs({"info", dir / "old.ply"});
  EXPECT_NE(info.out.find("none recorded"), std::string::npos) << info.out;
}

}  // namespace
}  // namespace hisnegs
