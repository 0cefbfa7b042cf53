// gmf/rasterize: rasterize_mixture against direct evaluation of the mixture.
#include "gmf/rasterize.hpp"

#include <gtest/gtest.h>

#include <array>
#include <vector>

#include "gmf/gaussian_mixture.hpp"
#include "gmf/psnr.hpp"
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

}  // namespace
}  // namespace hisnegs::gmf
