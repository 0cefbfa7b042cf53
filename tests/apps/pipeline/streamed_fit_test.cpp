// SPDX-License-Identifier: Apache-2.0
// How the streamed fit shares bricks among MPI ranks (apps/pipeline/streamed_fit.hpp):
// heaviest first to the least-loaded rank, the same answer on every rank.
#include "apps/pipeline/streamed_fit.hpp"

#include <gtest/gtest.h>

#include <vector>

namespace hisnegs::apps {
namespace {

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

}  // namespace
}  // namespace hisnegs::apps
