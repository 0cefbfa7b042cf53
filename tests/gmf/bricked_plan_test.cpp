// SPDX-License-Identifier: Apache-2.0
// Brick plans of the streamed fit: cores tile the stack, regions are the cores with
// their halo, every centre has exactly one owner, a kept Gaussian's support stays
// inside its brick's region (the halo bound), and a region's own frame maps to the
// stack's world points by the stated shift.
#include "gmf/bricked/brick_plan.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"

namespace hisnegs::gmf {
namespace {

TEST(BrickPlan, CoresTileTheStackOnceAndRegionsAddTheHalo) {
  const std::array<int, 3> shape{100, 70, 33}, halo{5, 4, 2};
  const BrickPlan plan = plan_bricks(shape, {32, 32, 32}, halo);
  EXPECT_EQ(plan.count, (std::array<int, 3>{4, 3, 2}));
  ASSERT_EQ(plan.bricks.size(), 24u);
  std::vector<int> owner(static_cast<std::size_t>(shape[0] * shape[1] * shape[2]), 0);
  for (const StreamBrick& b : plan.bricks) {
    for (int a = 0; a < 3; ++a) {
      EXPECT_EQ(b.region.lo[a], std::max(0, b.core.lo[a] - halo[a]));
      EXPECT_EQ(b.region.hi[a], std::min(shape[a], b.core.hi[a] + halo[a]));
    }
    for (int z = b.core.lo[2]; z < b.core.hi[2]; ++z)
      for (int y = b.core.lo[1]; y < b.core.hi[1]; ++y)
        for (int x = b.core.lo[0]; x < b.core.hi[0]; ++x) ++owner[static_cast<std::size_t>((z * shape[1] + y) * shape[0] + x)];
  }
  for (int n : owner) ASSERT_EQ(n, 1);
  EXPECT_NE(plan.describe().find("4 x 3 x 2 = 24 bricks"), std::string::npos) << plan.describe();
}

TEST(BrickPlan, BricksOfOneColourShareNoFaceEdgeOrCorner) {
  const BrickPlan plan = plan_bricks({64, 64, 64}, {16, 16, 16}, {2, 2, 2});
  for (const StreamBrick& a : plan.bricks) {
    for (const StreamBrick& b : plan.bricks) {
      if (a.id == b.id || a.colour() != b.colour()) continue;
      int far = 0;
      for (int k = 0; k < 3; ++k) far = std::max(far, std::abs(a.cell[k] - b.cell[k]));
      EXPECT_GE(far, 2) << a.id << " " << b.id;
    }
  }
}

TEST(BrickPlan, EveryCentreHasTheOwnerWhoseCoreHoldsItsVoxel) {
  const io::WorldFrame frame(50, 40, 20, Eigen::Vector3d(1.0, 0.8, 0.4));
  const BrickPlan plan = plan_bricks({50, 40, 20}, {16, 16, 16}, {3, 3, 3});
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.2, 1.2);  // also outside the box
  for (int i = 0; i < 2000; ++i) {
    const Eigen::Vector3d p(u(rng), 0.8 * u(rng), 0.4 * u(rng));
    const int id = plan.owner(frame, p);
    ASSERT_GE(id, 0);
    ASSERT_LT(id, static_cast<int>(plan.bricks.size()));
    const Eigen::Vector3d ijk = frame.index_from_world(p);
    const StreamBrick& b = plan.bricks[static_cast<std::size_t>(id)];
    for (int a = 0; a < 3; ++a) {
      const double c = std::clamp(std::floor(ijk[a] + 0.5), 0.0, static_cast<double>(plan.shape[a] - 1));
      EXPECT_GE(c, b.core.lo[a]);
      EXPECT_LT(c, b.core.hi[a]);
    }
  }
}

// The halo bound: a Gaussian centred in a core with every scale <= s_max has its
// whole support (dᵀΣ⁻¹d <= δ) inside the brick's region where the region ends at a
// neighbour, checked on the support's exact axis-aligned extent (sqrt(δ Σ_aa)) for
// random rotations and anisotropic voxels.
TEST(BrickPlan, AKeptGaussiansSupportStaysInsideItsRegion) {
  const io::WorldFrame frame(120, 90, 30, Eigen::Vector3d(1.0, 0.75, 0.6));  // z voxels 2.7x larger
  const double cutoff = 16.0, s_max = 6 * frame.voxel_size().minCoeff();
  const std::array<int, 3> halo = halo_voxels(frame, cutoff, s_max);
  const BrickPlan plan = plan_bricks({120, 90, 30}, {40, 40, 40}, halo);
  std::mt19937 rng(9);
  std::uniform_real_distribution<double> u(-1.0, 1.0), s(std::log(0.2 * frame.voxel_size().minCoeff()), std::log(s_max));
  for (int i = 0; i < 3000; ++i) {
    GaussianParams g;
    const Eigen::Vector3d p(u(rng), 0.75 * u(rng), 0.6 * u(rng));
    for (int a = 0; a < 3; ++a) {
      g.mean[a] = static_cast<float>(p[a]);
      g.log_scale[a] = static_cast<float>(s(rng));
    }
    Eigen::Vector4d q(u(rng), u(rng), u(rng), u(rng));
    q.normalize();
    for (int a = 0; a < 4; ++a) g.rotation[a] = static_cast<float>(q[a]);
    const Eigen::Matrix3d cov = covariance<double>(g);
    const StreamBrick& b = plan.bricks[static_cast<std::size_t>(plan.owner(frame, p))];
    const Eigen::Vector3d ijk = frame.index_from_world(p);
    for (int a = 0; a < 3; ++a) {
      const double reach = std::sqrt(cutoff * cov(a, a)) / frame.voxel_size()[a];
      // (at the stack's own faces the region ends where the stack does, as a whole fit's)
      if (b.region.lo[a] > 0) {
        EXPECT_GE(ijk[a] - reach, b.region.lo[a] - 0.5) << "axis " << a;
      }
      if (b.region.hi[a] < plan.shape[a]) {
        EXPECT_LE(ijk[a] + reach, b.region.hi[a] - 0.5) << "axis " << a;
      }
    }
  }
}

TEST(BrickPlan, ARegionFrameKeepsTheVoxelAndShiftsToTheStack) {
  const io::WorldFrame stack(64, 48, 20, Eigen::Vector3d(1.0, 0.75, 0.9));
  const io::VoxelBox region{{10, 5, 3}, {40, 30, 17}};
  const RegionFrame r = region_frame(stack, region);
  EXPECT_TRUE(r.frame.voxel_size().isApprox(stack.voxel_size(), 1e-12));
  for (const Eigen::Vector3d& local : {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(29, 24, 13), Eigen::Vector3d(3.5, 7.25, 1)}) {
    const Eigen::Vector3d global = local + Eigen::Vector3d(region.lo[0], region.lo[1], region.lo[2]);
    EXPECT_TRUE((r.frame.world_from_index(local) + r.shift).isApprox(stack.world_from_index(global), 1e-12));
  }
}

}  // namespace
}  // namespace hisnegs::gmf
