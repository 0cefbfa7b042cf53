// SPDX-License-Identifier: Apache-2.0
// How the bricked fit is planned and shares bricks among MPI ranks
// (gmf/bricked/memory_plan.hpp, gmf/bricked/schedule.hpp): heaviest first to the
// least-loaded rank, the same answer on every rank; and which Gaussians its seam
// pass refits.
#include "gmf/bricked/memory_plan.hpp"
#include "gmf/bricked/schedule.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "io/error.hpp"

namespace hisnegs::gmf {
namespace {

// --brick-voxels is bounded: below the smallest core the options refuse it; a plan
// of more bricks than the limit is refused before it is made, naming the limit.
TEST(FitPlan, BrickCoresAndCountsAreBounded) {
  GmfOptions gmf;
  gmf.stream_brick_voxels = 1;
  try {
    gmf.validate();
    ADD_FAILURE() << "a core of 1 voxel was accepted";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("stream_brick_voxels = 1: must be 0 (planned from max_memory) or at least 8"),
              std::string::npos)
        << e.what();
  }
  gmf.stream_brick_voxels = 8;
  EXPECT_NO_THROW(gmf.validate());
  const io::WorldFrame small(32, 64, 64, Eigen::Vector3d::Ones());
  EXPECT_EQ(choose_fit_plan({32, 64, 64}, small, gmf).plan.bricks.size(), 4u * 8u * 8u);
  const io::WorldFrame large(4096, 4096, 64, Eigen::Vector3d::Ones());
  try {
    (void)choose_fit_plan({4096, 4096, 64}, large, gmf);
    ADD_FAILURE() << "2,097,152 bricks were planned";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("more than the limit of 20000"), std::string::npos) << e.what();
  }
}

TEST(BrickRanks, HeaviestFirstToTheLeastLoadedRank) {
  const std::vector<int> ids{3, 5, 8, 9, 12};
  const std::vector<double> w{4, 9, 2, 6, 1};  // by position in ids
  const auto weight = [&](int id) {
    for (std::size_t i = 0; i < ids.size(); ++i) {
      if (ids[i] == id) return w[i];
    }
    return 0.0;
  };
  // 9 -> rank 0 (loads 9, 0); 6 -> 1 (9, 6); 4 -> 1 (9, 10); 2 -> 0 (11, 10); 1 -> 1 (11, 11)
  EXPECT_EQ(brick_ranks(ids, 2, weight), (std::vector<int>{1, 0, 0, 1, 1}));
  EXPECT_EQ(brick_ranks(ids, 1, weight), (std::vector<int>(5, 0)));
  // Equal weights: the earlier id to the lower rank, round robin.
  EXPECT_EQ(brick_ranks({0, 1, 2, 3}, 3, [](int) { return 1.0; }), (std::vector<int>{0, 1, 2, 0}));
  // More ranks than bricks: the rest get none.
  EXPECT_EQ(brick_ranks({7}, 4, [](int) { return 5.0; }), (std::vector<int>{0}));
}

// Shares follow the work: a brick whose core holds most of the foreground is a rank's
// whole share, however small it is; empty bricks count by the voxels read.
TEST(BrickRanks, SharesFollowTheForegroundOfTheCores) {
  const std::vector<double> foreground{50000, 100, 0, 200};  // by brick id
  const double core_voxels = 64.0 * 64 * 64;
  const auto weight = [&](int id) { return brick_work(foreground[static_cast<std::size_t>(id)], core_voxels); };
  EXPECT_EQ(share_of_bricks({0, 1, 2, 3}, weight, 0, 2), (std::vector<int>{0}));
  EXPECT_EQ(share_of_bricks({0, 1, 2, 3}, weight, 1, 2), (std::vector<int>{1, 2, 3}));
  EXPECT_EQ(share_of_bricks({0, 1, 2, 3}, weight, 0, 1), (std::vector<int>{0, 1, 2, 3}));
  EXPECT_DOUBLE_EQ(brick_work(0, 4000), 1.0);  // reading 4000 voxels ~ fitting one foreground voxel
  EXPECT_GT(brick_work(0, core_voxels), 0.0);  // an empty brick still costs its reading
}

// The foreground of every brick's core from one pass of slabs equals each core's
// own count, for slabs of pages and of bands of rows; parts of the pass (as the
// ranks read them; their sum left out here) add up to it.
TEST(CoreForeground, APassOfSlabsCountsEachCore) {
  io::Volume v;
  v.nx = 37, v.ny = 29, v.nz = 11;
  v.stored_as = io::SampleType::kUint16;
  v.voxels.resize(v.size());
  std::mt19937_64 rng(7);
  std::uniform_int_distribution<int> value(0, 4000);
  for (float& x : v.voxels) x = static_cast<float>(value(rng));
  const auto source = io::memory_source(v);
  io::Normalization map;
  map.method = io::NormalizationMethod::kMinMax;
  map.raw_lo = 0;
  map.raw_hi = 4000;
  const double threshold = 0.6;
  const BrickPlan plan = plan_bricks({v.nx, v.ny, v.nz}, {16, 10, 4}, {2, 2, 1});
  std::vector<std::int64_t> expected(plan.bricks.size(), 0);
  for (const StreamBrick& b : plan.bricks) {
    for (int z = b.core.lo[2]; z < b.core.hi[2]; ++z) {
      for (int y = b.core.lo[1]; y < b.core.hi[1]; ++y) {
        for (int x = b.core.lo[0]; x < b.core.hi[0]; ++x) {
          const float n = (v.voxels[v.index(x, y, z)] - 0.0f) / 4000.0f;
          expected[static_cast<std::size_t>(b.id)] += n > threshold ? 1 : 0;
        }
      }
    }
  }
  ASSERT_EQ(plan.bricks.size(), 3u * 3 * 3);
  for (const std::size_t slab : {std::size_t{4 * 37 * 3}, std::size_t{4 * 37 * 29 * 4}, std::size_t{1} << 30}) {
    EXPECT_EQ(core_foreground_counts(*source, map, plan, threshold, slab), expected) << "slab " << slab;
    std::vector<std::int64_t> parts(plan.bricks.size(), 0);
    for (int part = 0; part < 4; ++part) {
      io::ScanShare share;
      share.part = part;
      share.parts = 4;
      share.sum = [](std::span<double>) {};  // each part's own counts
      const std::vector<std::int64_t> mine = core_foreground_counts(*source, map, plan, threshold, slab, share);
      for (std::size_t id = 0; id < parts.size(); ++id) parts[id] += mine[id];
    }
    EXPECT_EQ(parts, expected) << "slab " << slab;
  }
}

// The seam pass refits a Gaussian when its own support (4σ at δ = 16, a quarter
// more and a voxel) reaches a face its brick shares: not when it is merely within
// the halo of one, nor for the stack's own faces; an elongated one by its extent
// along the face's normal.
TEST(SeamPass, RefitsTheGaussiansWhoseSupportReachesASharedFace) {
  const io::WorldFrame frame(64, 32, 16, Eigen::Vector3d(1.0, 0.5, 0.25));  // voxels of 1/32 world
  const BrickPlan plan = plan_bricks({64, 32, 16}, {32, 32, 16}, {8, 8, 8});  // shared face at x = 31.5
  ASSERT_EQ(plan.bricks.size(), 2u);
  const double voxel = frame.voxel_size().x();
  const auto gaussian = [&](double i, double sx, double sy) {  // centre (i, 16, 8), σ in voxels, axis-aligned
    GaussianParams g;
    const Eigen::Vector3d p = frame.world_from_index(Eigen::Vector3d(i, 16, 8));
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(p[a]);
    g.log_scale = {static_cast<float>(std::log(sx * voxel)), static_cast<float>(std::log(sy * voxel)),
                   static_cast<float>(std::log(0.5 * voxel))};
    return g;
  };
  const auto reaches = [&](int brick, const GaussianParams& g) {
    return reaches_shared_face(plan, frame, 16.0, plan.bricks[static_cast<std::size_t>(brick)], g);
  };
  // σ 0.5 voxel: support 2 voxels, reach 3.5 voxels from the face
  EXPECT_FALSE(reaches(0, gaussian(27.0, 0.5, 0.5)));  // 4.5 voxels away: within the halo (8) only
  EXPECT_TRUE(reaches(0, gaussian(29.0, 0.5, 0.5)));   // 2.5 voxels away
  EXPECT_TRUE(reaches(1, gaussian(34.0, 0.5, 0.5)));   // the same from the other side
  EXPECT_FALSE(reaches(1, gaussian(36.0, 0.5, 0.5)));
  // σ 3 voxels: support 12 voxels, the reach bounded by the halo (8)
  EXPECT_TRUE(reaches(0, gaussian(25.0, 3.0, 3.0)));
  EXPECT_FALSE(reaches(0, gaussian(22.0, 3.0, 3.0)));
  // long along y, thin along x (the face's normal): thin; then turned 90° about z
  GaussianParams needle = gaussian(27.0, 0.5, 4.0);
  EXPECT_FALSE(reaches(0, needle));
  needle.rotation = {static_cast<float>(std::sqrt(0.5)), 0.0f, 0.0f, static_cast<float>(std::sqrt(0.5))};
  EXPECT_TRUE(reaches(0, needle));
  // the stack's own faces are shared with no brick
  EXPECT_FALSE(reaches(0, gaussian(1.0, 3.0, 3.0)));
  EXPECT_FALSE(reaches(1, gaussian(62.0, 3.0, 3.0)));
}

}  // namespace
}  // namespace hisnegs::gmf
