// SPDX-License-Identifier: Apache-2.0
// Tests of apps/simulate/synthetic_neuron: determinism, the io::Volume contract (shape, spacing,
// uint16 counts), realistic sparsity, soma brightest, skeleton sanity, validation.
#include "apps/simulate/synthetic_neuron.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <map>
#include <string>
#include <type_traits>
#include <vector>

#include "io/error.hpp"

namespace hisnegs::simulate {
namespace {

// A small stack that still holds the default soma (radius 4 µm + 1 µm margins).
SyntheticNeuronOptions small_options(std::uint64_t seed = 7) {
  SyntheticNeuronOptions o;
  o.nx = 64;
  o.ny = 56;
  o.nz = 20;
  o.seed = seed;
  return o;
}

// The default stack and its skeleton, generated once for the suite (~0.1 s).
struct DefaultStack {
  io::Volume volume;
  std::vector<NeuriteNode> skeleton;
  SyntheticNeuronCounts counts;
};
const DefaultStack& default_stack() {
  static const DefaultStack stack = [] {
    DefaultStack s;
    s.volume = make_synthetic_neuron(SyntheticNeuronOptions{}, &s.skeleton, &s.counts);
    return s;
  }();
  return stack;
}

double zero_fraction(const io::Volume& v) {
  const auto n = std::count(v.voxels.begin(), v.voxels.end(), 0.0f);
  return static_cast<double>(n) / static_cast<double>(v.size());
}

// Runs validate() and returns the io::InputError message ("" if nothing was thrown).
std::string validation_error(const SyntheticNeuronOptions& o) {
  try {
    o.validate();
  } catch (const io::InputError& e) {
    return e.what();
  }
  return "";
}

TEST(SyntheticNeuron, SameSeedGivesBitIdenticalVolume) {
  const io::Volume a = make_synthetic_neuron(small_options(11));
  const io::Volume b = make_synthetic_neuron(small_options(11));
  ASSERT_EQ(a.voxels.size(), b.voxels.size());
  EXPECT_TRUE(a.voxels == b.voxels);
}

TEST(SyntheticNeuron, ResultDoesNotDependOnThreadCount) {
  const io::Volume parallel = make_synthetic_neuron(small_options(12));
  io::Volume serial;
  {
    tbb::global_control one_thread(tbb::global_control::max_allowed_parallelism, 1);
    serial = make_synthetic_neuron(small_options(12));
  }
  EXPECT_TRUE(parallel.voxels == serial.voxels);
}

TEST(SyntheticNeuron, DifferentSeedGivesDifferentVolume) {
  const io::Volume a = make_synthetic_neuron(small_options(1));
  const io::Volume b = make_synthetic_neuron(small_options(2));
  ASSERT_EQ(a.voxels.size(), b.voxels.size());
  std::size_t differing = 0;
  for (std::size_t i = 0; i < a.voxels.size(); ++i) differing += a.voxels[i] != b.voxels[i];
  // Different morphology, not only different noise: thousands of voxels change.
  EXPECT_GT(differing, a.voxels.size() / 200);
}

TEST(SyntheticNeuron, ValuesAreIntegralCountsInUint16Range) {
  const io::Volume& v = default_stack().volume;
  for (const float x : v.voxels) {
    ASSERT_EQ(x, std::round(x));
    ASSERT_GE(x, 0.0f);
    ASSERT_LE(x, 65535.0f);
  }
  EXPECT_GT(*std::max_element(v.voxels.begin(), v.voxels.end()), 50.0f);
  EXPECT_EQ(default_stack().counts.saturated, 0);
}

TEST(SyntheticNeuron, ShapeSpacingAndProvenanceAreAsRequested) {
  SyntheticNeuronOptions o;
  o.nx = 40;
  o.ny = 56;
  o.nz = 24;
  o.spacing_um = {0.5, 0.4, 1.2};
  o.seed = 42;
  const io::Volume v = make_synthetic_neuron(o);
  EXPECT_EQ(v.nx, 40);
  EXPECT_EQ(v.ny, 56);
  EXPECT_EQ(v.nz, 24);
  EXPECT_EQ(v.voxels.size(), std::size_t{40} * 56 * 24);
  EXPECT_EQ(v.stored_as, io::SampleType::kUint16);
  EXPECT_EQ(v.spacing.um, o.spacing_um);
  for (const io::SpacingSource s : v.spacing.source) EXPECT_EQ(s, io::SpacingSource::kUser);
  EXPECT_EQ(v.normalization.method, io::NormalizationMethod::kNone);
  EXPECT_EQ(v.source, "synthetic (seed 42)");
}

// After minmax normalization, as ../shared/data/README.md measures the real stacks
// (fg = voxels above 0.2; 0.07-0.3 % there, 0.2-5 % wanted here, where the smaller
// field of view holds relatively more neuron), with a background mostly exactly 0.
TEST(SyntheticNeuron, DefaultIsSparseLikeTheRealStacks) {
  io::Volume v = default_stack().volume;
  normalize(v, io::NormalizationOptions{});
  const io::VolumeStats stats = compute_stats(v, 0.2);
  EXPECT_EQ(stats.min, 0.0);
  EXPECT_NEAR(stats.max, 1.0, 1e-6);
  EXPECT_GE(stats.foreground_fraction, 0.002);
  EXPECT_LE(stats.foreground_fraction, 0.05);
  EXPECT_GE(zero_fraction(v), 0.80);
  EXPECT_LE(stats.nonzero_fraction, 0.20);
}

TEST(SyntheticNeuron, BackgroundSubtractionIsCountedAndOptional) {
  const DefaultStack& s = default_stack();
  const auto zeros = static_cast<std::int64_t>(zero_fraction(s.volume) * s.volume.size() + 0.5);
  // Clipped voxels (raw < threshold) are a subset of the zeros (raw <= threshold).
  EXPECT_GT(s.counts.clipped_to_zero, 0);
  EXPECT_LE(s.counts.clipped_to_zero, zeros);

  SyntheticNeuronOptions o = small_options();
  o.background_subtract = false;
  SyntheticNeuronCounts counts;
  const io::Volume raw = make_synthetic_neuron(o, nullptr, &counts);
  EXPECT_EQ(counts.clipped_to_zero, 0);
  // Without subtraction the background sits at the camera offset (100 ± 2 counts).
  const float lo = *std::min_element(raw.voxels.begin(), raw.voxels.end());
  EXPECT_GT(lo, o.camera_offset - 8 * o.read_noise);
  EXPECT_EQ(zero_fraction(raw), 0.0);
}

// Every voxel holding the maximum lies in the soma: within its radius plus the PSF
// reach (3 sigma) and one voxel of the soma centre (skeleton node 0).
void expect_max_in_soma(const io::Volume& v, const std::vector<NeuriteNode>& skeleton, const SyntheticNeuronOptions& o) {
  ASSERT_FALSE(skeleton.empty());
  ASSERT_EQ(skeleton[0].parent, -1);
  const Eigen::Vector3d centre = skeleton[0].position_um;
  const float hi = *std::max_element(v.voxels.begin(), v.voxels.end());
  const double reach = o.soma_radius_um + 3 * o.psf_sigma_z_um + o.spacing_um[2];
  int maxima = 0;
  for (int z = 0; z < v.nz; ++z) {
    for (int y = 0; y < v.ny; ++y) {
      for (int x = 0; x < v.nx; ++x) {
        if (v.at(x, y, z) != hi) continue;
        ++maxima;
        const Eigen::Vector3d p(x * o.spacing_um[0], y * o.spacing_um[1], z * o.spacing_um[2]);
        EXPECT_LE((p - centre).norm(), reach) << "maximum at voxel " << x << ", " << y << ", " << z;
      }
    }
  }
  EXPECT_GE(maxima, 1);
}

TEST(SyntheticNeuron, SomaIsTheBrightestRegion) {
  expect_max_in_soma(default_stack().volume, default_stack().skeleton, SyntheticNeuronOptions{});
  for (const std::uint64_t seed : {2u, 3u, 4u}) {
    const SyntheticNeuronOptions o = small_options(seed);
    std::vector<NeuriteNode> skeleton;
    const io::Volume v = make_synthetic_neuron(o, &skeleton);
    expect_max_in_soma(v, skeleton, o);
  }
}

TEST(SyntheticNeuron, SkeletonIsATreeInsideTheBox) {
  const SyntheticNeuronOptions o;
  const std::vector<NeuriteNode>& skeleton = default_stack().skeleton;
  ASSERT_GT(skeleton.size(), 100u);  // a branching arbor, not a lone soma
  EXPECT_EQ(skeleton[0].parent, -1);
  EXPECT_DOUBLE_EQ(skeleton[0].radius_um, o.soma_radius_um);
  const int n[3] = {o.nx, o.ny, o.nz};
  int forks = 0;
  std::vector<int> children(skeleton.size(), 0);
  for (std::size_t i = 0; i < skeleton.size(); ++i) {
    const NeuriteNode& node = skeleton[i];
    for (int a = 0; a < 3; ++a) {
      EXPECT_GE(node.position_um[a], 0.0) << "node " << i;
      EXPECT_LE(node.position_um[a], (n[a] - 1) * o.spacing_um[a]) << "node " << i;
    }
    if (i == 0) continue;
    ASSERT_GE(node.parent, 0);
    ASSERT_LT(node.parent, static_cast<int>(i));  // parents come first
    EXPECT_GE(node.radius_um, o.min_radius_um);
    EXPECT_GT(node.brightness, 0.0);
    EXPECT_LT(node.brightness, 1.0);  // neurites dimmer than the soma
    ++children[node.parent];
    if (node.parent != 0 && children[node.parent] == 2) ++forks;
  }
  EXPECT_EQ(children[0], o.primary_branches);
  EXPECT_GE(forks, 3);
}

TEST(SyntheticNeuronOptions, ValidateRejectsBadFieldsNamingThem) {
  EXPECT_EQ(validation_error(SyntheticNeuronOptions{}), "");

  SyntheticNeuronOptions o;
  o.nx = 0;
  EXPECT_EQ(validation_error(o), "synth.nx = 0: must be in [8, 4096]");

  o = {};
  o.spacing_um[2] = -1;
  EXPECT_NE(validation_error(o).find("spacing_um[2] = -1"), std::string::npos);

  o = {};
  o.min_radius_um = 2;
  EXPECT_NE(validation_error(o).find("min_radius_um = 2"), std::string::npos);
  EXPECT_NE(validation_error(o).find("max_radius_um"), std::string::npos);

  o = {};
  o.nz = 8;  // 7 µm of z cannot hold a soma of radius 4 µm
  EXPECT_NE(validation_error(o).find("soma_radius_um = 4"), std::string::npos);

  o = {};
  o.peak_photons = std::nan("");
  EXPECT_NE(validation_error(o).find("peak_photons = nan"), std::string::npos);
}

TEST(SyntheticNeuronOptions, MakeSyntheticNeuronValidatesFirst) {
  SyntheticNeuronOptions o = small_options();
  o.primary_branches = 0;
  EXPECT_THROW((void)make_synthetic_neuron(o), io::InputError);
}

TEST(SyntheticNeuronOptions, VisitNamesEveryFieldOnceAndCanSetIt) {
  SyntheticNeuronOptions o;
  std::map<std::string, int> seen;
  o.visit([&](const char* name, auto& field) {
    ++seen[name];
    if constexpr (std::is_same_v<std::decay_t<decltype(field)>, int>) {
      if (std::string(name) == "nx") field = 77;
    }
  });
  for (const auto& [name, count] : seen) EXPECT_EQ(count, 1) << name;
  for (const char* name :
       {"nx", "ny", "nz", "spacing_um", "seed", "primary_branches", "soma_radius_um", "max_radius_um", "min_radius_um",
        "branch_probability_per_um", "psf_sigma_xy_um", "psf_sigma_z_um", "peak_photons", "read_noise", "camera_offset",
        "background_subtract", "background_subtract_sigmas"}) {
    EXPECT_EQ(seen.count(name), 1u) << name;
  }
  EXPECT_EQ(o.nx, 77);
}

}  // namespace
}  // namespace hisnegs::simulate
