// gmf/samples: extract_samples takes the active voxels of a sparse grid as
// weighted samples.
#include "gmf/samples.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "io/sparse_grid.hpp"

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
  EXPECT_EQ(s.brick_begin.back(), s.size());
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

}  // namespace
}  // namespace hisnegs::gmf
