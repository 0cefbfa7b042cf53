// gmf/brick_index: which Gaussians reach which sample brick.
#include "gmf/brick_index.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

namespace hisnegs::gmf {
namespace {

TEST(BrickIndex, ListsExactlyTheGaussiansWhoseSupportReachesABrick) {
  // A 32^3 volume in the unit box; bricks at origins (0,0,0) and (24,24,24).
  const io::WorldFrame frame(32, 32, 32, Eigen::Vector3d::Ones());
  SampleSet s;
  s.brick_begin = {0, 1, 2};
  s.brick_origin = {{0, 0, 0}, {24, 24, 24}};
  for (int b = 0; b < 2; ++b) {
    const Eigen::Vector3d p = frame.world_from_index(Eigen::Vector3d(b * 24 + 3, b * 24 + 3, b * 24 + 3));
    s.x.push_back(p.x());
    s.y.push_back(p.y());
    s.z.push_back(p.z());
    s.value.push_back(1);
    s.weight.push_back(1);
  }
  GaussianMixture mix;
  auto add = [&](const Eigen::Vector3d& ijk, double sigma_voxels) {
    GaussianParams g;
    const Eigen::Vector3d p = frame.world_from_index(ijk);
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(p[a]);
    for (int a = 0; a < 3; ++a) g.log_scale[a] = static_cast<float>(std::log(sigma_voxels * frame.voxel_size()[a]));
    mix.push_back(g);
  };
  add({3, 3, 3}, 1.0);     // inside brick 0
  add({12, 3, 3}, 1.0);    // 4σ = 4 voxels: reaches x = 8.. -> not brick 0 (centres 0..7)
  add({10, 3, 3}, 1.0);    // reaches x = 6: touches brick 0
  add({16, 16, 16}, 3.0);  // 4σ = 12 voxels: reaches 4..28 -> both bricks
  add({28, 28, 28}, 0.5);  // brick 1 only
  const BrickIndex index = build_brick_index(mix, s, frame, 16.0);
  const auto b0 = index.of(0), b1 = index.of(1);
  EXPECT_EQ(std::vector<std::uint32_t>(b0.begin(), b0.end()), (std::vector<std::uint32_t>{0, 2, 3}));
  EXPECT_EQ(std::vector<std::uint32_t>(b1.begin(), b1.end()), (std::vector<std::uint32_t>{3, 4}));
}

}  // namespace
}  // namespace hisnegs::gmf
