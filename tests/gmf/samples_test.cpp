// SPDX-License-Identifier: Apache-2.0
// gmf/samples: extract_samples takes every active voxel of both parts of a
// sparse grid once, at its world position with its value, grouped into
// contiguous blocks of `block`³ voxels, background samples weighted
// sqrt(background_weight / fraction).
#include "gmf/samples.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <map>
#include <random>
#include <set>
#include <stdexcept>

#include "gmf/block_index.hpp"
#include "gmf/core/density_ops.hpp"
#include "gmf/core/gaussian_math.hpp"
#include "gmf/objective.hpp"
#include "io/sparse_grid.hpp"
#include "tests/gmf/gmf_test_scenes.hpp"

namespace hisnegs::gmf {
namespace {

TEST(Samples, ExtractsForegroundAndWeightedBackground) {
  io::Volume v;
  v.nx = v.ny = v.nz = 16;
  v.voxels.assign(v.size(), 0.0f);
  v.at(5, 5, 5) = 1.0f;
  io::SparseGridOptions o;
  o.threshold = 0.5;
  o.band_voxels = 1;
  o.background_fraction = 0.25;
  o.seed = 3;
  const io::SparseGrid grid = io::build_sparse_grid(v, Eigen::Vector3d::Ones(), o);
  const SampleSet s = extract_samples(grid, 2.0);
  EXPECT_EQ(s.foreground, 27);
  EXPECT_EQ(s.background, grid.background_voxels());
  EXPECT_EQ(s.size(), static_cast<std::size_t>(s.foreground + s.background));
  EXPECT_EQ(s.block_begin.back(), s.size());
  double bright = 0;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s.value[i] == 1.0) {
      bright += 1;
      const Eigen::Vector3d p = grid.frame().world_from_index(Eigen::Vector3d(5, 5, 5));
      EXPECT_DOUBLE_EQ(s.x[i], p.x());
      EXPECT_EQ(s.weight[i], 1.0);
    }
    if (i >= static_cast<std::size_t>(s.foreground)) {
      EXPECT_DOUBLE_EQ(s.weight[i], std::sqrt(2.0 / 0.25));
    }
  }
  EXPECT_EQ(bright, 1);
}

// 21 × 13 × 11 voxels (leaves cut by every face) of scattered foreground and
// 20% background samples.
io::SparseGrid small_grid(double background_fraction) {
  io::Volume v;
  v.nx = 21;
  v.ny = 13;
  v.nz = 11;
  v.source = "samples";
  v.normalization.method = io::NormalizationMethod::kMinMax;
  std::mt19937_64 rng(89);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  v.voxels.resize(v.size());
  for (float& x : v.voxels) x = u(rng) < 0.03f ? 0.4f + 0.6f * u(rng) : 0.1f * u(rng);
  io::SparseGridOptions o;
  o.threshold = 0.3;
  o.band_voxels = 1;
  o.background_fraction = background_fraction;
  o.seed = 5;
  return io::build_sparse_grid(v, Eigen::Vector3d(1.0, 13.0 / 21, 11.0 / 21), o);
}

using Index = std::array<int, 3>;

// The active voxels of one part, by index.
std::map<Index, float> active(const io::SparseGrid& grid, io::SparseGridPart part) {
  std::map<Index, float> out;
  grid.visit_active_leaves(part, [&](const auto&, auto voxels) {
    for (const io::ActiveVoxel& v : voxels) out[v.index] = v.value;
  });
  return out;
}

// The sample's voxel index, recovered from its world position (exact: the
// position must be world_from_index of an integer index).
Index index_of(const io::WorldFrame& frame, const SampleSet& s, std::size_t i) {
  const Eigen::Vector3d p(s.x[i], s.y[i], s.z[i]);
  const Eigen::Vector3d ijk = frame.index_from_world(p);
  const Index idx = {static_cast<int>(std::lround(ijk.x())), static_cast<int>(std::lround(ijk.y())),
                     static_cast<int>(std::lround(ijk.z()))};
  const Eigen::Vector3d back = frame.world_from_index(Eigen::Vector3d(idx[0], idx[1], idx[2]));
  EXPECT_EQ(back, p) << "sample " << i;
  return idx;
}

// Foreground samples first (weight 1), then background ones: each active voxel
// of each part exactly once, with its value.
TEST(Samples, EveryActiveVoxelOnceWithItsWorldPositionAndValue) {
  const io::SparseGrid grid = small_grid(0.2);
  const io::WorldFrame frame = grid.frame();
  const auto fg = active(grid, io::SparseGridPart::kForeground);
  const auto bg = active(grid, io::SparseGridPart::kBackground);
  ASSERT_GT(fg.size(), 50u);
  ASSERT_GT(bg.size(), 50u);
  const SampleSet s = extract_samples(grid, 1.0, 2);
  ASSERT_EQ(s.foreground, static_cast<std::int64_t>(fg.size()));
  ASSERT_EQ(s.background, static_cast<std::int64_t>(bg.size()));
  ASSERT_EQ(s.size(), fg.size() + bg.size());
  ASSERT_EQ(s.x.size(), s.size());
  ASSERT_EQ(s.y.size(), s.size());
  ASSERT_EQ(s.z.size(), s.size());
  ASSERT_EQ(s.weight.size(), s.size());
  std::set<Index> seen_fg, seen_bg;
  for (std::size_t i = 0; i < s.size(); ++i) {
    const Index idx = index_of(frame, s, i);
    const bool is_fg = i < fg.size();
    const auto& part = is_fg ? fg : bg;
    const auto it = part.find(idx);
    ASSERT_NE(it, part.end()) << "sample " << i << " is no active voxel of its part";
    EXPECT_EQ(s.value[i], static_cast<double>(it->second)) << "sample " << i;
    EXPECT_TRUE((is_fg ? seen_fg : seen_bg).insert(idx).second) << "voxel sampled twice, sample " << i;
    if (is_fg) {
      EXPECT_EQ(s.weight[i], 1.0);
    }
  }
  EXPECT_EQ(seen_fg.size(), fg.size());
  EXPECT_EQ(seen_bg.size(), bg.size());
}

// Blocks are contiguous runs of samples, non-empty, in order; every sample lies in
// its block of `block`³ voxels from block_origin (a multiple of `block`);
// within one part no block appears twice. For every allowed block edge.
TEST(Samples, BlocksAreContiguousForEveryBlockSize) {
  const io::SparseGrid grid = small_grid(0.2);
  for (const int block : {1, 2, 4, 8}) {
    const SampleSet s = extract_samples(grid, 1.0, block);
    EXPECT_EQ(s.block, block);
    ASSERT_EQ(s.block_begin.size(), s.blocks() + 1) << "block " << block;
    EXPECT_EQ(s.block_begin.front(), 0u);
    EXPECT_EQ(s.block_begin.back(), s.size());
    std::set<Index> origins_fg, origins_bg;
    for (std::size_t b = 0; b < s.blocks(); ++b) {
      ASSERT_LT(s.block_begin[b], s.block_begin[b + 1]) << "empty block " << b << ", block " << block;
      const Index& o = s.block_origin[b];
      for (int a = 0; a < 3; ++a) EXPECT_EQ(o[a] % block, 0) << "block index " << b << ", block " << block;
      // A block holds samples of one part only.
      const bool is_fg = s.block_begin[b] < s.foreground;
      EXPECT_EQ(is_fg, s.block_begin[b + 1] <= s.foreground) << "block index " << b << " straddles the parts";
      EXPECT_TRUE((is_fg ? origins_fg : origins_bg).insert(o).second) << "block twice, index " << b;
      for (std::uint32_t i = s.block_begin[b]; i < s.block_begin[b + 1]; ++i) {
        const Index idx = index_of(grid.frame(), s, i);
        for (int a = 0; a < 3; ++a) {
          EXPECT_GE(idx[a], o[a]) << "sample " << i << ", block " << block;
          EXPECT_LT(idx[a], o[a] + block) << "sample " << i << ", block " << block;
        }
      }
    }
    if (block < 8) {
      // Finer blocks split leaves: more blocks than with block 8.
      EXPECT_GT(s.blocks(), extract_samples(grid, 1.0, 8).blocks()) << "block " << block;
    }
  }
}

// The shell outside the box: a foreground that touches the x = 0 and z = nz − 1
// faces gets, beyond each of its face voxels, `depth` samples along the outward
// normal, value 0, weight 1, as background, in blocks whose origin is a multiple of
// the block edge (negative at x < 0); none beyond faces it does not touch.
TEST(Samples, OutsideShellBeyondForegroundOnTheFaces) {
  io::Volume v;
  v.nx = 13;
  v.ny = 10;
  v.nz = 7;
  v.voxels.assign(v.size(), 0.0f);
  for (int y = 3; y < 6; ++y) {
    v.at(0, y, 3) = 1.0f;  // on the x = 0 face
    v.at(6, y, 6) = 0.8f;  // on the z = nz − 1 face
  }
  io::SparseGridOptions o;
  o.threshold = 0.5;
  o.band_voxels = 0;
  const io::SparseGrid grid = io::build_sparse_grid(v, Eigen::Vector3d::Ones(), o);
  const SampleSet inside = extract_samples(grid, 1.0, 2);
  for (const int depth : {1, 2, 3}) {
    const SampleSet s = extract_samples(grid, 1.0, 2, depth);
    ASSERT_EQ(s.foreground, inside.foreground);
    EXPECT_EQ(s.background, inside.background + 2 * 3 * depth) << "depth " << depth;
    std::set<Index> seen;
    for (std::size_t b = 0; b < s.blocks(); ++b) {
      const Index& bo = s.block_origin[b];
      for (int a = 0; a < 3; ++a) EXPECT_EQ(((bo[a] % 2) + 2) % 2, 0);
      for (std::uint32_t i = s.block_begin[b]; i < s.block_begin[b + 1]; ++i) {
        if (i < inside.size()) continue;
        const Index idx = index_of(grid.frame(), s, i);
        EXPECT_EQ(s.value[i], 0.0);
        EXPECT_EQ(s.weight[i], 1.0);
        EXPECT_TRUE(seen.insert(idx).second) << "twice";
        for (int a = 0; a < 3; ++a) {
          EXPECT_GE(idx[a], bo[a]);
          EXPECT_LT(idx[a], bo[a] + 2);
        }
        const bool beyond_x = idx[0] < 0 && idx[0] >= -depth && idx[1] >= 3 && idx[1] < 6 && idx[2] == 3;
        const bool beyond_z = idx[2] >= 7 && idx[2] < 7 + depth && idx[0] == 6 && idx[1] >= 3 && idx[1] < 6;
        EXPECT_TRUE(beyond_x || beyond_z) << idx[0] << " " << idx[1] << " " << idx[2];
      }
    }
    EXPECT_EQ(seen.size(), static_cast<std::size_t>(2 * 3 * depth));
    // The block index reaches the outside blocks: a Gaussian on the x = 0 face
    // lists every block of the shell beyond it, and none beyond the z face.
    GaussianMixture m;
    m.push_back(
        isotropic_gaussian(grid.frame().world_from_index(Eigen::Vector3d(0, 4, 3)), grid.frame().voxel_size(), 0.9));
    const BlockIndex index = build_block_index(m, s, grid.frame(), 16.0);
    for (std::size_t b = 0; b < s.blocks(); ++b) {
      if (s.block_begin[b] < inside.size()) continue;
      EXPECT_EQ(index.of(b).size(), s.block_origin[b][0] < 0 ? 1u : 0u) << "block " << b;
    }
  }
  EXPECT_THROW((void)extract_samples(grid, 1.0, 2, 9), std::invalid_argument);
}

TEST(Samples, OtherBlockSizesAreRefused) {
  const io::SparseGrid grid = small_grid(0.0);
  for (const int block : {0, -2, 3, 5, 16}) {
    EXPECT_THROW((void)extract_samples(grid, 1.0, block), std::invalid_argument) << block;
  }
}

// Background samples stand for 1 / fraction voxels: weight sqrt(background_weight
// / fraction); none when either is 0.
TEST(Samples, BackgroundWeightIsSqrtOfWeightOverFraction) {
  const io::SparseGrid grid = small_grid(0.2);
  const SampleSet s = extract_samples(grid, 3.0, 4);
  ASSERT_GT(s.background, 0);
  for (std::size_t i = static_cast<std::size_t>(s.foreground); i < s.size(); ++i) {
    EXPECT_DOUBLE_EQ(s.weight[i], std::sqrt(3.0 / 0.2)) << "sample " << i;
  }
  const SampleSet unweighted = extract_samples(grid, 0.0, 4);
  EXPECT_EQ(unweighted.background, 0);
  EXPECT_EQ(unweighted.size(), static_cast<std::size_t>(unweighted.foreground));
  const SampleSet no_background = extract_samples(small_grid(0.0), 3.0, 4);
  EXPECT_EQ(no_background.background, 0);
}

// jitter_samples: each sample within ±jitter/2 voxel of its centre per axis, its
// target the CONVENTIONS trilinear value there (the outside shell stays 0), weights
// and blocks kept; a pure function of (samples, seed), whatever the thread count.
TEST(JitterSamples, MovesWithinTheVoxelWithTrilinearTargets) {
  const Scene scene = make_scene(5);
  const SampleSet centres = extract_samples(grid_of(scene, 0.05), 1.0, 2, 2);
  ASSERT_GT(centres.background, 0);
  const Eigen::Vector3d voxel = scene.frame.voxel_size();
  for (const double jitter : {0.5, 1.0}) {
    const SampleSet s = jitter_samples(centres, scene.volume, scene.frame, jitter, 7);
    ASSERT_EQ(s.size(), centres.size());
    EXPECT_EQ(s.block_begin, centres.block_begin);
    EXPECT_EQ(s.block_origin, centres.block_origin);
    EXPECT_EQ(s.weight, centres.weight);
    double largest[3] = {0, 0, 0};
    std::size_t moved = 0;
    for (std::size_t i = 0; i < s.size(); ++i) {
      const double d[3] = {(s.x[i] - centres.x[i]) / voxel.x(), (s.y[i] - centres.y[i]) / voxel.y(),
                           (s.z[i] - centres.z[i]) / voxel.z()};
      for (int a = 0; a < 3; ++a) largest[a] = std::max(largest[a], std::abs(d[a]));
      moved += d[0] != 0 ? 1 : 0;
      const Eigen::Vector3d p(s.x[i], s.y[i], s.z[i]);
      ASSERT_EQ(s.value[i], static_cast<double>(io::sample_trilinear(scene.volume, scene.frame, p))) << i;
      if (centres.value[i] == 0.0 && centres.weight[i] == 1.0 && !scene.frame.contains(p)) {
        EXPECT_EQ(s.value[i], 0.0);
      }
    }
    EXPECT_EQ(moved, s.size());
    for (int a = 0; a < 3; ++a) {
      EXPECT_LE(largest[a], 0.5 * jitter) << "axis " << a;
      EXPECT_GT(largest[a], 0.45 * jitter) << "axis " << a;  // the whole range is used
    }
  }
  // Deterministic in the seed, independent of the thread count; 0 = the centres.
  const SampleSet a = jitter_samples(centres, scene.volume, scene.frame, 1.0, 11);
  SampleSet one_thread;
  {
    tbb::global_control serial(tbb::global_control::max_allowed_parallelism, 1);
    one_thread = jitter_samples(centres, scene.volume, scene.frame, 1.0, 11);
  }
  EXPECT_EQ(a.x, one_thread.x);
  EXPECT_EQ(a.value, one_thread.value);
  EXPECT_NE(a.x, jitter_samples(centres, scene.volume, scene.frame, 1.0, 12).x);
  const SampleSet same = jitter_samples(centres, scene.volume, scene.frame, 0.0, 11);
  EXPECT_EQ(same.x, centres.x);
  EXPECT_EQ(same.value, centres.value);
  EXPECT_THROW((void)jitter_samples(centres, scene.volume, scene.frame, 1.5, 0), std::invalid_argument);
}

// The block index padded by jitter_reach (half a voxel per axis) lists, for every
// block, every Gaussian whose support reaches one of its moved samples: on cubic
// voxels and on voxels 4x longer in z (where a pad of half the x voxel misses some).
TEST(JitterSamples, PaddedBlockIndexReachesEveryMovedSample) {
  Scene cubic = make_scene(6);
  Scene long_z = cubic;
  long_z.frame = io::WorldFrame(48, 48, 12, Eigen::Vector3d(1.0, 1.0, 1.0));
  long_z.volume.nz = 12;
  long_z.volume.voxels = rasterize_mixture(long_z.truth, long_z.frame, {.cutoff = 1e9});
  ASSERT_NEAR(long_z.frame.voxel_size().z(), 4 * long_z.frame.voxel_size().x(), 1e-12);
  for (const Scene* scene : {&cubic, &long_z}) {
    SCOPED_TRACE(scene == &cubic ? "cubic voxels" : "z voxels 4x longer");
    const SampleSet s =
        jitter_samples(extract_samples(grid_of(*scene, 0.05), 1.0, 2), scene->volume, scene->frame, 1.0, 3);
    GaussianMixture m = scene->truth;
    for (GaussianParams& g : m) {
      for (float& l : g.log_scale) l += std::log(0.4f);  // small: supports end within a few voxels
    }
    const double cutoff = 16.0;
    const auto missed_reaches = [&](const Eigen::Vector3d& pad, std::size_t& reached) {
      const BlockIndex index = build_block_index(m, s, scene->frame, cutoff, 1.0, pad);
      std::size_t missed = 0;
      for (std::size_t b = 0; b < s.blocks(); ++b) {
        const auto listed = index.of(b);
        for (std::size_t k = 0; k < m.size(); ++k) {
          const GaussianFrame<double> f = frame_of(m[k]);
          bool reaches = false;
          for (std::uint32_t i = s.block_begin[b]; i < s.block_begin[b + 1] && !reaches; ++i) {
            const double x[3] = {s.x[i], s.y[i], s.z[i]};
            double z[3];
            reaches = mahalanobis(f, x, z) <= cutoff;
          }
          if (!reaches) continue;
          ++reached;
          missed += std::find(listed.begin(), listed.end(), static_cast<std::uint32_t>(k)) == listed.end() ? 1 : 0;
        }
      }
      return missed;
    };
    std::size_t reached = 0;
    EXPECT_EQ(missed_reaches(jitter_reach(scene->frame, 1.0), reached), 0u);
    EXPECT_GT(reached, 100u);
    if (scene == &long_z) {
      std::size_t ignored = 0;
      EXPECT_GT(missed_reaches(Eigen::Vector3d::Constant(0.5 * scene->frame.voxel_size().x()), ignored), 0u)
          << "the test cannot tell a per-axis pad from the smallest one";
    }
  }
}

// Why the fit moves its samples: a bright Gaussian thinner than a voxel, between
// voxel centres, is invisible to the centres (its support reaches none of them)
// but shows in every MIP through it; moved samples see it.
TEST(JitterSamples, SeeASubVoxelSpeckTheCentresMiss) {
  const Scene scene = make_scene(8);
  const SampleSet centres = extract_samples(grid_of(scene, 0.05), 1.0, 2);
  const Eigen::Vector3d voxel = scene.frame.voxel_size();
  // Specks between the centres (at voxel corners) next to every 25th foreground
  // sample, σ 0.2 voxel: m at the nearest centres = 3 (0.5 / 0.2)² = 18.75 > δ = 16.
  GaussianMixture specked = scene.truth;
  for (std::size_t i = 0; i < static_cast<std::size_t>(centres.foreground); i += 25) {
    const Eigen::Vector3d corner(centres.x[i] + 0.5 * voxel.x(), centres.y[i] + 0.5 * voxel.y(),
                                 centres.z[i] + 0.5 * voxel.z());
    specked.push_back(isotropic_gaussian(corner, 0.2 * voxel, 0.95));
  }
  ASSERT_GT(specked.size(), scene.truth.size() + 50);
  for (const MixtureModel model : {MixtureModel{.cutoff = 16.0},
                                   MixtureModel{.aggregation = Aggregation::kSoftmax, .beta = 64.0, .cutoff = 16.0}}) {
    const auto objective_loss = [&](const SampleSet& s, const GaussianMixture& m) {
      const BlockIndex index = build_block_index(m, s, scene.frame, model.cutoff, 1.0, 0.5 * voxel.maxCoeff());
      const FitObjective objective(s, index, m.size(), model);
      std::vector<double> x(objective.parameters());
      for (std::size_t k = 0; k < m.size(); ++k) {
        const auto a = to_array(m[k]);
        for (int i = 0; i < kGaussianParamCount; ++i) x[kGaussianParamCount * k + i] = a[i];
      }
      return objective.evaluate(x.data(), nullptr);
    };
    const double base = objective_loss(centres, scene.truth);
    EXPECT_NEAR(objective_loss(centres, specked), base, 1e-12 * base);
    const SampleSet moved = jitter_samples(centres, scene.volume, scene.frame, 1.0, 0);
    const double seen = objective_loss(moved, specked) - objective_loss(moved, scene.truth);
    EXPECT_GT(seen, 1.0);  // measured: +15.1 (sum), +13.1 (softmax)
  }
}

}  // namespace
}  // namespace hisnegs::gmf
