// SPDX-License-Identifier: Apache-2.0
// gmf/rasterize: BlockRasterizer's block values against a direct double-precision
// evaluation (every voxel of every block, and zero wherever no block reaches),
// the cutoff, tail and clip rules, determinism across thread counts,
// rasterize_mixture on a frame whose edges cut blocks, and refusal of supports
// that leave the index range.
#include "gmf/core/rasterize.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "gmf/core/gaussian_math.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/core/psnr.hpp"
#include "io/error.hpp"
#include "tests/gmf/gmf_test_scenes.hpp"

namespace hisnegs::gmf {
namespace {

TEST(GmfRasterize, MatchesDirectEvaluation) {
  const Scene scene = make_scene(5);
  const std::vector<float> f = rasterize_mixture(scene.truth, scene.frame, {.cutoff = 1e9});
  for (const auto& [x, y, z] : std::vector<std::array<int, 3>>{{10, 10, 10}, {24, 30, 12}, {40, 5, 3}}) {
    const double direct = evaluate_mixture(scene.truth, scene.frame.world_from_index(Eigen::Vector3d(x, y, z)));
    EXPECT_NEAR(f[scene.volume.index(x, y, z)], direct, 1e-6);
  }
  EXPECT_GT(psnr(f, scene.volume.voxels), 100.0);  // identical up to float rounding
}

// K Gaussians with random rotations, means uniform in centre ± spread (world),
// σ uniform in [sigma_lo, sigma_hi] per axis and a in [0.2, 0.9].
GaussianMixture random_mixture(std::mt19937_64& rng, int k, const Eigen::Vector3d& centre, double spread,
                               double sigma_lo, double sigma_hi) {
  std::uniform_real_distribution<double> u(-1, 1), s(sigma_lo, sigma_hi), a(0.2, 0.9);
  std::normal_distribution<double> n(0, 1);
  GaussianMixture m;
  for (int i = 0; i < k; ++i) {
    GaussianParams g;
    for (int d = 0; d < 3; ++d) g.mean[d] = static_cast<float>(centre[d] + spread * u(rng));
    for (int d = 0; d < 3; ++d) g.log_scale[d] = static_cast<float>(std::log(s(rng)));
    Eigen::Vector4d q(n(rng), n(rng), n(rng), n(rng));
    q.normalize();
    for (int d = 0; d < 4; ++d) g.rotation[d] = static_cast<float>(q[d]);
    const double ai = a(rng);
    g.intensity_logit = static_cast<float>(std::log(ai / (1 - ai)));
    m.push_back(g);
  }
  return m;
}

// Σ_k of the terms the options count at x: m_k(x) <= cutoff and a_k e^{-m_k/2} >= tail.
double direct(const std::vector<GaussianFrame<double>>& frames, const double x[3], const RasterizeOptions& o) {
  double f = 0;
  for (const auto& fr : frames) {
    double z[3];
    if (!(mahalanobis(fr, x, z) <= o.cutoff)) continue;
    const double g = evaluate_gaussian<double>(fr, x, nullptr);
    if (g >= o.tail) f += g;
  }
  return f;
}

struct Coverage {
  std::size_t voxels = 0;        // voxels in some block
  std::size_t nonzero = 0;       // of them, with a counted term
  std::size_t dropped = 0;       // of them, with an uncounted term (beyond the cutoff or below the tail)
  std::size_t outside_clip = 0;  // of them, outside the clip box but reached by some Gaussian
};

bool inside(const VoxelLattice& lattice, const Eigen::Vector3i& v) {
  return !lattice.clip ||
         ((v.array() >= lattice.clip->min.array()).all() && (v.array() <= lattice.clip->max.array()).all());
}

// Every voxel of every block equals `direct` within 1e-12 (the same terms in the
// same order, in double: only exp and the summation may round differently) and
// 0 outside the clip; every voxel of the index cube ±region outside all blocks
// has no counted term.
Coverage expect_blocks_match_direct(const GaussianMixture& mixture, const VoxelLattice& lattice,
                                    const RasterizeOptions& options, int region) {
  std::vector<GaussianFrame<double>> frames;
  for (const auto& g : mixture) frames.push_back(frame_of(g));
  const RasterizeOptions all{};  // every term
  const auto world = [&](const Eigen::Vector3i& v, double x[3]) {
    for (int d = 0; d < 3; ++d) x[d] = lattice.origin_world[d] + lattice.voxel_size_world[d] * v[d];
  };
  const BlockRasterizer raster(mixture, lattice, options, "test mixture");
  Coverage c;
  std::set<std::array<int, 3>> covered;
  int mismatches = 0;
  for (std::size_t b = 0; b < raster.blocks(); ++b) {
    const Eigen::Vector3i o = raster.block_origin(b);
    for (int d = 0; d < 3; ++d) EXPECT_EQ(o[d] % kRasterBlockDim, 0) << "block " << b;
    BlockValues values;
    raster.evaluate(b, values);
    for (int i = 0; i < kRasterBlockDim; ++i)
      for (int j = 0; j < kRasterBlockDim; ++j)
        for (int k = 0; k < kRasterBlockDim; ++k) {
          const Eigen::Vector3i v = o + Eigen::Vector3i(i, j, k);
          EXPECT_TRUE(covered.insert({v.x(), v.y(), v.z()}).second) << "voxel in two blocks";
          double x[3];
          world(v, x);
          const double counted = direct(frames, x, options);
          const double expected = inside(lattice, v) ? counted : 0.0;
          if (std::abs(values[block_offset(i, j, k)] - expected) > 1e-12 && ++mismatches <= 5) {
            ADD_FAILURE() << "voxel " << v.transpose() << ": " << values[block_offset(i, j, k)] << " vs " << expected;
          }
          ++c.voxels;
          c.nonzero += expected > 0 ? 1 : 0;
          c.dropped += direct(frames, x, all) > counted ? 1 : 0;
          c.outside_clip += !inside(lattice, v) && counted > 0 ? 1 : 0;
        }
  }
  EXPECT_EQ(mismatches, 0);
  int uncovered = 0;
  for (int i = -region; i <= region; ++i)
    for (int j = -region; j <= region; ++j)
      for (int k = -region; k <= region; ++k) {
        if (covered.count({i, j, k})) continue;
        const Eigen::Vector3i v(i, j, k);
        double x[3];
        world(v, x);
        if (inside(lattice, v) && direct(frames, x, options) != 0.0 && ++uncovered <= 5) {
          ADD_FAILURE() << "voxel " << v.transpose() << " has counted terms but no block";
        }
      }
  EXPECT_EQ(uncovered, 0);
  return c;
}

// Unclipped lattice of 0.1 world units, Gaussians of σ 0.08-0.25 around the
// origin (so blocks of negative indices occur), cutoff δ = 9: inside each block,
// terms beyond m = 9 are left out.
// mixture_psnr (no rasterized volume held) equals psnr of the rasterized volume:
// a perturbed mixture against the scene's volume, as a sum and as a softmax, with
// a cutoff small enough that most voxels lie outside every support.
TEST(GmfRasterize, MixturePsnrEqualsThePsnrOfTheRasterizedVolume) {
  const Scene scene = make_scene(41);
  GaussianMixture m = scene.truth;
  for (auto& g : m) {
    g.mean[0] += 0.7f * static_cast<float>(scene.frame.voxel_size().x());
    g.intensity_logit -= 0.3f;
  }
  for (const RasterizeOptions options :
       {RasterizeOptions{.cutoff = 9.0}, RasterizeOptions{.cutoff = 16.0, .aggregation = Aggregation::kSoftmax,
                                                          .beta = 32.0}}) {
    const double expected = psnr(rasterize_mixture(m, scene.frame, options), scene.volume.voxels);
    const double streamed = mixture_psnr(m, scene.frame, options, scene.volume.voxels);
    EXPECT_GT(expected, 10.0);
    EXPECT_LT(expected, 80.0);
    EXPECT_NEAR(streamed, expected, 1e-9);
  }
  EXPECT_THROW((void)mixture_psnr(m, scene.frame, {}, std::span<const float>(scene.volume.voxels).first(10)),
               std::invalid_argument);
}

TEST(GmfRasterize, BlockValuesEqualDirectEvaluationWithinTheCutoff) {
  std::mt19937_64 rng(41);
  const GaussianMixture m = random_mixture(rng, 6, Eigen::Vector3d::Zero(), 1.0, 0.08, 0.25);
  // Supports reach |x| <= 1 + 3 · 0.25 world = 17.5 voxels.
  const Coverage c = expect_blocks_match_direct(m, VoxelLattice::aligned(0.1), {.cutoff = 9.0}, 24);
  EXPECT_GT(c.nonzero, 1000u);
  EXPECT_GT(c.dropped, 1000u);  // the cutoff mattered
}

// tail = 0.05: a term counts where a e^{-m/2} >= 0.05 (m <= 2 ln(a / 0.05)); a
// Gaussian with a below the tail never counts, even at its centre.
TEST(GmfRasterize, TailDropsFaintTermsAndFaintGaussians) {
  std::mt19937_64 rng(43);
  GaussianMixture m = random_mixture(rng, 5, Eigen::Vector3d(0.3, -0.2, 0.1), 0.8, 0.1, 0.2);
  GaussianParams faint;
  faint.mean = {-1.5f, 1.5f, -1.5f};
  faint.log_scale = {std::log(0.2f), std::log(0.2f), std::log(0.2f)};
  faint.intensity_logit = std::log(0.04f / 0.96f);  // a = 0.04 < tail
  m.push_back(faint);
  const RasterizeOptions tail{.tail = 0.05};
  const Coverage c = expect_blocks_match_direct(m, VoxelLattice::aligned(0.1), tail, 26);
  EXPECT_GT(c.nonzero, 500u);
  EXPECT_GT(c.dropped, 1000u);
  // The faint Gaussian alone rasterizes to nothing.
  const BlockRasterizer alone(GaussianMixture({faint}), VoxelLattice::aligned(0.1), tail, "faint");
  EXPECT_EQ(alone.blocks(), 0u);
}

// A clip box whose faces cut blocks: block voxels outside it stay 0 though
// Gaussians reach them, and those inside equal the direct value.
TEST(GmfRasterize, ClipBoxLeavesVoxelsOutsideAtZero) {
  std::mt19937_64 rng(47);
  const GaussianMixture m = random_mixture(rng, 6, Eigen::Vector3d::Zero(), 0.8, 0.1, 0.25);
  VoxelLattice lattice = VoxelLattice::aligned(0.1);
  lattice.clip = VoxelLattice::IndexBox{Eigen::Vector3i(-5, -3, -7), Eigen::Vector3i(4, 6, 2)};
  const Coverage c = expect_blocks_match_direct(m, lattice, {.cutoff = 16.0}, 24);
  EXPECT_GT(c.nonzero, 100u);
  EXPECT_GT(c.outside_clip, 100u);  // the clip mattered
}

// The same values bit for bit with one and with two TBB threads, for the
// rasterizer's blocks and for rasterize_mixture.
TEST(GmfRasterize, ResultsAreIdenticalForOneAndTwoThreads) {
  std::mt19937_64 rng(53);
  const io::WorldFrame frame(40, 36, 20, Eigen::Vector3d(1.0, 0.9, 0.5));
  // Many overlapping Gaussians, so blocks sum many terms, and enough of them that
  // the (block, Gaussian) pairs are produced by several TBB tasks.
  const GaussianMixture m = random_mixture(rng, 3000, Eigen::Vector3d::Zero(), 0.9, 0.02, 0.08);
  auto run = [&](int threads, std::vector<std::array<int, 3>>& origins, std::vector<double>& blocks) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    const BlockRasterizer raster(m, VoxelLattice::of(frame), {.cutoff = 16.0}, "threads");
    BlockValues values;
    for (std::size_t b = 0; b < raster.blocks(); ++b) {
      const Eigen::Vector3i o = raster.block_origin(b);
      origins.push_back({o.x(), o.y(), o.z()});
      raster.evaluate(b, values);
      blocks.insert(blocks.end(), values.begin(), values.end());
    }
    return rasterize_mixture(m, frame, {.cutoff = 16.0});
  };
  std::vector<std::array<int, 3>> o1;
  std::vector<double> b1;
  const std::vector<float> f1 = run(1, o1, b1);
  EXPECT_GT(o1.size(), 8u);
  // Scheduling varies from run to run: three runs on two threads.
  for (int repeat = 0; repeat < 3; ++repeat) {
    std::vector<std::array<int, 3>> o2;
    std::vector<double> b2;
    const std::vector<float> f2 = run(2, o2, b2);
    EXPECT_EQ(o1, o2);
    EXPECT_EQ(b1, b2);
    EXPECT_EQ(f1, f2);
  }
}

// 13 × 7 × 5 voxels: one and a half blocks along x, less than one along y and z,
// Gaussians near and beyond the edges. Every voxel is the float of the direct
// value (δ = 16), which 4 ulps cover (the double sums may round differently).
TEST(GmfRasterize, NonCubicFrameMatchesEvaluationVoxelByVoxel) {
  const io::WorldFrame frame(13, 7, 5, Eigen::Vector3d(1.0, 7.0 / 13, 5.0 / 13));
  std::mt19937_64 rng(59);
  const GaussianMixture m = random_mixture(rng, 12, Eigen::Vector3d::Zero(), 1.1, 0.1, 0.3);
  const RasterizeOptions o{.cutoff = 16.0};
  const std::vector<float> f = rasterize_mixture(m, frame, o);
  ASSERT_EQ(f.size(), 13u * 7u * 5u);
  std::vector<GaussianFrame<double>> frames;
  for (const auto& g : m) frames.push_back(frame_of(g));
  int nonzero = 0;
  for (int z = 0; z < 5; ++z)
    for (int y = 0; y < 7; ++y)
      for (int x = 0; x < 13; ++x) {
        const Eigen::Vector3d p = frame.world_from_index(Eigen::Vector3d(x, y, z));
        const double xw[3] = {p.x(), p.y(), p.z()};
        const double expected = direct(frames, xw, o);
        EXPECT_FLOAT_EQ(f[(static_cast<std::size_t>(z) * 7 + y) * 13 + x], static_cast<float>(expected))
            << x << " " << y << " " << z;
        nonzero += expected > 0 ? 1 : 0;
      }
  EXPECT_GT(nonzero, 13 * 7 * 5 / 2);
}

// Voxels of 1e-9 world units on an unclipped lattice put a support of σ 0.1
// beyond voxel index ±2^23: refused with a message naming the model.
TEST(GmfRasterize, TinyVoxelsOnAnUnclippedLatticeAreRefusedNamingTheModel) {
  GaussianParams g;
  g.log_scale = {std::log(0.1f), std::log(0.1f), std::log(0.1f)};
  try {
    const BlockRasterizer raster(GaussianMixture({g}), VoxelLattice::aligned(1e-9), {.cutoff = 16.0},
                                 "models/big-model.ply");
    FAIL() << "no error for " << raster.blocks() << " blocks";
  } catch (const io::InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("models/big-model.ply"), std::string::npos) << what;
    EXPECT_NE(what.find("reach past voxel index"), std::string::npos) << what;  // the range check, not the memory one
    EXPECT_NE(what.find("larger voxel size"), std::string::npos) << what;
  }
  // The same Gaussian at 0.01 world units per voxel is fine.
  const BlockRasterizer ok(GaussianMixture({g}), VoxelLattice::aligned(0.01), {.cutoff = 16.0}, "small");
  EXPECT_GT(ok.blocks(), 0u);
}

// A Gaussian with a NaN or Inf parameter is named as such, not reported as one that
// reaches past the lattice.
TEST(GmfRasterize, NonFiniteParametersAreNamed) {
  GaussianParams fine;
  fine.log_scale = {std::log(0.1f), std::log(0.1f), std::log(0.1f)};
  for (const float bad : {std::nanf(""), std::numeric_limits<float>::infinity()}) {
    GaussianParams g = fine;
    g.mean[1] = bad;
    try {
      const BlockRasterizer raster(GaussianMixture({fine, g}), VoxelLattice::aligned(0.01), {.cutoff = 16.0}, "m.ply");
      ADD_FAILURE() << "no error for " << raster.blocks() << " blocks";
    } catch (const io::InputError& e) {
      EXPECT_EQ(std::string(e.what()), "m.ply: Gaussian 1 has a non-finite parameter (NaN or Inf); nothing can be "
                                       "rasterized from it");
    }
  }
}

// A zero, negative or non-finite voxel size is refused.
TEST(GmfRasterize, InvalidVoxelSizeIsRefused) {
  for (const double v : {0.0, -0.5, std::nan("")}) {
    EXPECT_THROW(BlockRasterizer(GaussianMixture(), VoxelLattice::aligned(v), {}, "m"), io::InputError) << v;
  }
}

}  // namespace
}  // namespace hisnegs::gmf
