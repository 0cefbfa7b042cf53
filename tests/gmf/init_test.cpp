// gmf/init: grid initialization meets the Gaussian budget on the foreground.
#include "gmf/init.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "io/error.hpp"
#include "tests/gmf/gmf_test_scenes.hpp"

namespace hisnegs::gmf {
namespace {

TEST(GmfInit, MeetsTheBudgetOnTheForeground) {
  const Scene scene = make_scene(3);
  InitReport report;
  const GaussianMixture m = initialize_on_grid(scene.volume, scene.frame, 0.1, 60, &report);
  EXPECT_LE(m.size(), 60u);
  EXPECT_GE(m.size(), 30u);  // the search lands close to the budget
  EXPECT_GT(report.foreground, 0);
  for (const auto& g : m) {
    // Centres lie where the volume is bright.
    const Eigen::Vector3d ijk = scene.frame.index_from_world(Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2]));
    const int x = static_cast<int>(std::lround(ijk.x())), y = static_cast<int>(std::lround(ijk.y())),
              z = static_cast<int>(std::lround(ijk.z()));
    EXPECT_GT(scene.volume.at(x, y, z), 0.02f);
  }
  io::Volume empty = scene.volume;
  std::fill(empty.voxels.begin(), empty.voxels.end(), 0.0f);
  EXPECT_THROW((void)initialize_on_grid(empty, scene.frame, 0.1, 60), io::InputError);
}

}  // namespace
}  // namespace hisnegs::gmf
