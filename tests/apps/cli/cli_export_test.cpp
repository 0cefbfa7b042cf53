// SPDX-License-Identifier: Apache-2.0
// The `export` and `import` commands through the real binary on a small generated
// checkpoint: OpenVDB's own tools (vdb_print, the pyopenvdb binding) read the .vdb,
// the points round trip gives the same checkpoint file, the splat PLY, TIFF and
// compact exports, and bad input (one line, exit 2, no file left behind).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include "gmf/core/checkpoint.hpp"
#include "gmf/core/export_formats.hpp"
#include "io/load_volume.hpp"
#include "io/ply.hpp"
#include "io/tiff_stack.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {
namespace fs = std::filesystem;
using testing::run_hisnegs;

// OpenVDB's command-line printer (Debian libopenvdb-tools) and the Python binding
// (python3-openvdb), which loads only in Debian's own interpreter.
constexpr const char* kVdbPrint = "/usr/bin/vdb_print";
constexpr const char* kPython = "/usr/bin/python3";

class CliExport : public ::testing::Test {
 protected:
  testing::ScratchDir dir_;
  gmf::GaussianMixture mixture_;
  io::WorldFrame frame_;  // the stack the model was "fitted" to: 20 × 24 × 10, spacing 1, 1, 2 µm

  fs::path model() const { return dir_ / "m.ply"; }
  fs::path stack() const { return dir_ / "s.tif"; }

  // A checkpoint written as `fit` would (shape, spacing, aspect, normalization,
  // source) and a matching stack; Gaussians of 0.6-2.4 voxels.
  void SetUp() override {
    const io::VoxelSpacing spacing{{1.0, 1.0, 2.0},
                                   {io::SpacingSource::kUser, io::SpacingSource::kUser, io::SpacingSource::kUser}};
    const Eigen::Vector3d aspect = io::aspect_scales(20, 24, 10, spacing, io::AspectMode::kPhysical);
    frame_ = io::WorldFrame(20, 24, 10, aspect);
    std::mt19937 rng(11);
    std::uniform_real_distribution<float> u(-0.7f, 0.7f), log_scale(std::log(0.05f), std::log(0.2f)), logit(-2.f, 3.f);
    std::normal_distribution<float> quat(0.0f, 1.0f);
    for (int k = 0; k < 30; ++k) {
      gmf::GaussianParams g;
      for (int d = 0; d < 3; ++d) g.mean[d] = u(rng) * static_cast<float>(aspect[d]);
      for (float& v : g.log_scale) v = log_scale(rng);
      for (float& v : g.rotation) v = quat(rng);
      g.intensity_logit = logit(rng);
      mixture_.push_back(g);
    }
    gmf::CheckpointMeta meta;
    meta.volume_shape_zyx = std::array<int, 3>{10, 24, 20};
    meta.spacing_um = spacing.um;
    meta.aspect = std::array<double, 3>{aspect.x(), aspect.y(), aspect.z()};
    meta.normalization = "minmax 0 1";
    meta.extra = {{"source", stack().string()}};
    gmf::save_checkpoint(model(), mixture_, meta);

    std::vector<float> v(20 * 24 * 10);
    std::uniform_real_distribution<float> value(0.0f, 1.0f);
    for (float& x : v) x = value(rng);
    v[0] = 0.0f;
    v[1] = 1.0f;  // min-max normalization leaves the values as they are
    io::TiffWriteOptions o;
    o.spacing_um = spacing.um;
    io::write_tiff_stack(stack(), v, 20, 24, 10, o);
  }

  // Skips the test when `tool` is missing, except in CI (the environment variable
  // CI set), whose scripts/install-deps.sh installs it: there it is a failure.
  // Callers return when IsSkipped() || HasFatalFailure().
  static void require_installed(bool present, const std::string& tool) {
    if (present) return;
    if (std::getenv("CI")) FAIL() << tool << " is missing; scripts/install-deps.sh installs it";
    GTEST_SKIP() << tool << " is not installed";
  }
};

TEST_F(CliExport, VdbIsReadByOpenVdbsOwnTools) {
  const auto r = run_hisnegs({"export", "vdb", "--model", model(), "-o", dir_ / "m.vdb", "--points"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("the model's native voxels (20x24x10)"), std::string::npos) << r.out;

  require_installed(fs::exists(kVdbPrint), kVdbPrint);
  if (IsSkipped() || HasFatalFailure()) return;
  const testing::ShellResult listing = testing::run_shell(std::string(kVdbPrint) + " -l " + testing::shell_quoted(dir_ / "m.vdb"));
  ASSERT_EQ(listing.status, 0) << listing.out;
  EXPECT_NE(listing.out.find("density"), std::string::npos) << listing.out;
  EXPECT_NE(listing.out.find("gaussians"), std::string::npos) << listing.out;

  const bool binding = fs::exists(kPython) && testing::run_shell(std::string(kPython) + " -c 'import pyopenvdb'").status == 0;
  require_installed(binding, "pyopenvdb (python3-openvdb)");
  if (IsSkipped() || HasFatalFailure()) return;
  // Every 17th active voxel: index, world position by the grid's own transform, value.
  const std::string script =
      "import sys, pyopenvdb as vdb\n"
      "g = vdb.read(sys.argv[1], 'density')\n"
      "print('count', g.activeVoxelCount(), g.metadata['gaussians'])\n"
      "for n, it in enumerate(g.citerOnValues()):\n"
      "    if it.count == 1 and n % 17 == 0:\n"
      "        w = g.transform.indexToWorld(it.min)\n"
      "        print(*it.min, repr(w[0]), repr(w[1]), repr(w[2]), repr(it.value))\n";
  testing::write_text(dir_ / "read.py", script);
  const testing::ShellResult py = testing::run_shell(std::string(kPython) + " " + testing::shell_quoted(dir_ / "read.py") + " " + testing::shell_quoted(dir_ / "m.vdb"));
  ASSERT_EQ(py.status, 0) << py.out;
  std::istringstream lines(py.out);
  std::string word;
  long long count = 0, gaussians = 0;
  lines >> word >> count >> gaussians;
  ASSERT_EQ(word, "count") << py.out;
  EXPECT_EQ(gaussians, 30);
  EXPECT_NE(r.out.find(" " + std::to_string(count) + " active voxels"), std::string::npos) << r.out << py.out;
  int checked = 0;
  for (int i, j, k; lines >> i >> j >> k;) {
    double wx, wy, wz, value;
    lines >> wx >> wy >> wz >> value;
    const Eigen::Vector3d expect = frame_.world_from_index(Eigen::Vector3d(i, j, k));
    EXPECT_LT((Eigen::Vector3d(wx, wy, wz) - expect).norm(), 1e-12) << i << " " << j << " " << k;
    // The fitted f: each term inside the default support δ = 16 (issue 32, item 15).
    EXPECT_NEAR(value, gmf::evaluate_mixture(mixture_, expect, 16.0), 1e-5) << i << " " << j << " " << k;
    ++checked;
  }
  EXPECT_GE(checked, 5) << py.out;
}

TEST_F(CliExport, ImportGivesBackTheSameCheckpointFile) {
  ASSERT_EQ(run_hisnegs({"-q", "export", "vdb", "--model", model(), "-o", dir_ / "m.vdb", "--points"}).exit_code, 0);
  const auto r = run_hisnegs({"import", "vdb", dir_ / "m.vdb", "-o", dir_ / "back.ply"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("30 Gaussians"), std::string::npos) << r.out;
  // Same parameters bit for bit and the same metadata, hence the same bytes.
  EXPECT_EQ(testing::read_bytes(dir_ / "back.ply"), testing::read_bytes(model()));
}

TEST_F(CliExport, MatchVolumeAndVoxelSizeSetTheLattice) {
  // A stack of twice the resolution over the same world box: half the voxel size.
  io::TiffWriteOptions o;
  o.spacing_um = std::array<double, 3>{0.5, 0.5, 1.0};
  std::vector<float> v(40 * 48 * 20, 0.0f);
  v[0] = 1.0f;
  io::write_tiff_stack(dir_ / "fine.tif", v, 40, 48, 20, o);
  const auto fine =
      run_hisnegs({"export", "vdb", "--model", model(), "-o", dir_ / "fine.vdb", "--match-volume", dir_ / "fine.tif"});
  ASSERT_EQ(fine.exit_code, 0) << fine.err;
  const auto info = run_hisnegs({"info", dir_ / "fine.vdb"});
  ASSERT_EQ(info.exit_code, 0) << info.err;
  EXPECT_NE(info.out.find("voxel size (0.04167, 0.04167, 0.08333)"), std::string::npos) << info.out;

  const auto aligned = run_hisnegs({"export", "vdb", "--model", model(), "-o", dir_ / "v.vdb", "--voxel-size", "0.1"});
  ASSERT_EQ(aligned.exit_code, 0) << aligned.err;
  EXPECT_NE(run_hisnegs({"info", dir_ / "v.vdb"}).out.find("voxel size (0.1, 0.1, 0.1)"), std::string::npos);

  // A stack over another world box (different physical aspect) is refused.
  o.spacing_um = std::array<double, 3>{1.0, 1.0, 1.0};
  io::write_tiff_stack(dir_ / "other.tif", v, 40, 48, 20, o);
  const auto other = run_hisnegs(
      {"export", "vdb", "--model", model(), "-o", dir_ / "other.vdb", "--match-volume", dir_ / "other.tif"});
  EXPECT_EQ(other.exit_code, 2);
  EXPECT_NE(other.err.find("differs from the model's"), std::string::npos) << other.err;
  EXPECT_FALSE(fs::exists(dir_ / "other.vdb"));
}

TEST_F(CliExport, SplatPlyHasTheViewerFields) {
  const auto r =
      run_hisnegs({"export", "splat-ply", "--model", model(), "-o", dir_ / "splat.ply", "--colormap", "fire"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("not show a MIP"), std::string::npos) << r.out;
  const io::PlyTable t = io::read_ply(dir_ / "splat.ply");
  const io::PlyElement* v = t.find("vertex");
  ASSERT_NE(v, nullptr);
  ASSERT_EQ(v->count(), 30);
  for (const char* name : {"x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2",
                           "rot_0", "rot_1", "rot_2", "rot_3"}) {
    EXPECT_TRUE(v->find_property(name).has_value()) << name;
  }
  const std::vector<float> opacity = v->column_as<float>("opacity"), dc0 = v->column_as<float>("f_dc_0");
  for (std::size_t k = 0; k < mixture_.size(); ++k) {
    EXPECT_EQ(opacity[k], mixture_[k].intensity_logit);
    const double red = gmf::splat_color(gmf::intensity<double>(mixture_[k]), gmf::SplatColormap::kFire)[0];
    EXPECT_NEAR(0.5 + gmf::kShC0 * dc0[k], red, 1e-6);
  }
}

TEST_F(CliExport, VolumeIsTheResampledMixtureWithItsPsnr) {
  const auto r = run_hisnegs({"export", "volume", "--model", model(), "-o", dir_ / "f.tif", "--match-volume", stack()});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const io::Volume f = io::read_tiff_stack(dir_ / "f.tif");
  ASSERT_EQ(f.nx, 20);
  ASSERT_EQ(f.ny, 24);
  ASSERT_EQ(f.nz, 10);
  EXPECT_EQ(f.stored_as, io::SampleType::kFloat32);
  EXPECT_DOUBLE_EQ(f.spacing.um[2], 2.0);
  double sse = 0;
  const io::LoadedVolume truth = io::load_volume(stack(), io::VolumeOptions{});
  for (int z = 0; z < 10; ++z)
    for (int y = 0; y < 24; ++y)
      for (int x = 0; x < 20; ++x) {
        const double exact =
            gmf::evaluate_mixture(mixture_, frame_.world_from_index(Eigen::Vector3d(x, y, z)), 16.0);
        ASSERT_NEAR(f.at(x, y, z), exact, 1e-5) << x << " " << y << " " << z;
        sse += std::pow(static_cast<double>(f.at(x, y, z)) - truth.volume.at(x, y, z), 2);
      }
  char psnr[64];
  std::snprintf(psnr, sizeof psnr, "3D PSNR %.2f dB", 10.0 * std::log10(1.0 / (sse / f.size())));
  EXPECT_NE(r.out.find(psnr), std::string::npos) << r.out << "\nexpected " << psnr;

  // Without --match-volume: the model's own voxels, no PSNR.
  const auto native = run_hisnegs({"export", "volume", "--model", model(), "-o", dir_ / "n.tif"});
  ASSERT_EQ(native.exit_code, 0) << native.err;
  EXPECT_EQ(native.out.find("PSNR"), std::string::npos) << native.out;
  EXPECT_EQ(testing::read_bytes(dir_ / "n.tif"), testing::read_bytes(dir_ / "f.tif")) << "the same voxels and spacing";
}

TEST_F(CliExport, CompactIsSmallerAndEveryCommandReadsIt) {
  const auto r = run_hisnegs({"export", "compact", "--model", model(), "-o", dir_ / "m.hgs"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("30 Gaussians"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("B/Gaussian"), std::string::npos) << r.out;
  EXPECT_LT(fs::file_size(dir_ / "m.hgs"), fs::file_size(model()) / 2);
  EXPECT_EQ(gmf::load_checkpoint(dir_ / "m.hgs").meta, gmf::load_checkpoint(model()).meta);

  const auto info = run_hisnegs({"info", dir_ / "m.hgs"});
  ASSERT_EQ(info.exit_code, 0) << info.err;
  EXPECT_NE(info.out.find("compact (.hgs) version 2 (CRC-32 of the whole file matches)"), std::string::npos) << info.out;
  EXPECT_NE(info.out.find("gaussians    30 "), std::string::npos) << info.out;
  EXPECT_NE(info.out.find("normalized   minmax 0 1"), std::string::npos) << info.out;

  // Another command, by content: the resampled volumes of both files agree to what
  // the default bit depths allow (intensity within 1/512 per Gaussian, sizes 0.3 %).
  ASSERT_EQ(run_hisnegs({"-q", "export", "volume", "--model", dir_ / "m.hgs", "-o", dir_ / "c.tif"}).exit_code, 0);
  ASSERT_EQ(run_hisnegs({"-q", "export", "volume", "--model", model(), "-o", dir_ / "p.tif"}).exit_code, 0);
  const io::Volume c = io::read_tiff_stack(dir_ / "c.tif"), p = io::read_tiff_stack(dir_ / "p.tif");
  ASSERT_EQ(c.size(), p.size());
  double max_diff = 0, max_value = 0;
  for (std::size_t i = 0; i < c.size(); ++i) {
    max_diff = std::max(max_diff, std::abs(static_cast<double>(c.voxels[i]) - p.voxels[i]));
    max_value = std::max(max_value, static_cast<double>(p.voxels[i]));
  }
  EXPECT_GT(max_value, 0.3);
  EXPECT_LT(max_diff, 0.01);
  EXPECT_GT(max_diff, 0.0) << "the compact file is quantized";

  // Bad input: one line, exit 2, nothing written.
  fs::create_directories(dir_ / "out");
  const std::string bytes = testing::read_bytes(dir_ / "m.hgs");
  testing::write_text(dir_ / "cut.hgs", bytes.substr(0, bytes.size() - 7));
  const auto rejected = [&](const std::vector<std::string>& args, const std::string& needle) {
    const auto bad = run_hisnegs(args);
    EXPECT_EQ(bad.exit_code, 2) << needle << "\n" << bad.err;
    EXPECT_EQ(testing::count_lines(bad.err), 1) << bad.err;
    EXPECT_NE(bad.err.find(needle), std::string::npos) << bad.err;
    EXPECT_TRUE(fs::is_empty(dir_ / "out")) << needle << ": output left behind";
  };
  rejected({"export", "volume", "--model", dir_ / "cut.hgs", "-o", dir_ / "out" / "v.tif"},
           "cut.hgs: compact checkpoint: truncated");
  rejected({"export", "compact", "--model", dir_ / "cut.hgs", "-o", dir_ / "out" / "m.hgs"}, "truncated");
  rejected({"export", "compact", "--model", model(), "-o", dir_ / "out" / "m.hgs", "--position-bits", "40"},
           "--position-bits");
}

TEST_F(CliExport, BadInputIsOneLineAndLeavesNoFile) {
  fs::create_directories(dir_ / "out");
  const fs::path out = dir_ / "out" / "x.vdb";
  ASSERT_EQ(run_hisnegs({"-q", "export", "splat-ply", "--model", model(), "-o", dir_ / "splat.ply"}).exit_code, 0);
  ASSERT_EQ(run_hisnegs({"-q", "export", "vdb", "--model", model(), "-o", dir_ / "no_points.vdb"}).exit_code, 0);
  gmf::save_checkpoint(dir_ / "bare.ply", mixture_, gmf::CheckpointMeta{});
  const auto rejected = [&](const std::vector<std::string>& args, const std::string& needle) {
    const auto r = run_hisnegs(args);
    EXPECT_EQ(r.exit_code, 2) << args[1] << " " << needle << "\n" << r.err;
    EXPECT_EQ(testing::count_lines(r.err), 1) << r.err;
    EXPECT_NE(r.err.find(needle), std::string::npos) << r.err;
    EXPECT_TRUE(fs::is_empty(dir_ / "out")) << needle << ": output left behind";
  };
  rejected({"export", "vdb", "--model", dir_ / "missing.ply", "-o", out}, "missing.ply: no such file");
  // A splat PLY has x y z scale_* rot_* but no intensity_logit: not a checkpoint.
  rejected({"export", "vdb", "--model", dir_ / "splat.ply", "-o", out}, "no property 'intensity_logit'");
  rejected({"export", "volume", "--model", dir_ / "splat.ply", "-o", dir_ / "out" / "x.tif"}, "intensity_logit");
  rejected({"export", "splat-ply", "--model", dir_ / "splat.ply", "-o", dir_ / "out" / "x.ply"}, "intensity_logit");
  rejected({"export", "vdb", "--model", model(), "-o", out, "--voxel-size", "0"}, "--voxel-size = 0: must be");
  rejected({"export", "vdb", "--model", model(), "-o", out, "--voxel-size", "-0.1"}, "--voxel-size = -0.1");
  rejected({"export", "vdb", "--model", model(), "-o", out, "--cutoff", "0"}, "cutoff = 0");
  rejected({"export", "vdb", "--model", model(), "-o", out, "--voxel-size", "0.1", "--match-volume", stack()},
           "excludes");
  rejected({"export", "vdb", "--model", dir_ / "bare.ply", "-o", out}, "--voxel-size V or --match-volume");
  rejected({"export", "volume", "--model", dir_ / "bare.ply", "-o", dir_ / "out" / "x.tif"}, "--match-volume");
  rejected({"export", "splat-ply", "--model", model(), "-o", dir_ / "out" / "x.ply", "--colormap", "jet"}, "'jet'");
  rejected({"import", "vdb", dir_ / "no_points.vdb", "-o", dir_ / "out" / "m.ply"}, "no grid named 'gaussians'");
  rejected({"import", "vdb", model(), "-o", dir_ / "out" / "m.ply"}, "not a .vdb file");
}

}  // namespace
}  // namespace hisnegs
