// SPDX-License-Identifier: Apache-2.0
// gmf/core/halo: the stack's noise margin and the Gaussians brighter than the stack
// at their centre, on a constructed stack (a bright neurite in a noisy background).
#include "gmf/core/halo.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

namespace hisnegs::gmf {
namespace {

constexpr int kN = 24;

// A neurite of 0.8 along x at the centre, in a background of 0.05 ± sigma.
io::Volume neurite_in_noise(double sigma) {
  io::Volume v;
  v.nx = v.ny = v.nz = kN;
  v.voxels.resize(v.size());
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.0f, static_cast<float>(sigma));
  for (int z = 0; z < kN; ++z)
    for (int y = 0; y < kN; ++y)
      for (int x = 0; x < kN; ++x) v.at(x, y, z) = sigma > 0 ? std::max(0.0f, 0.05f + noise(rng)) : 0.0f;
  for (int x = 0; x < kN; ++x)
    for (int y = kN / 2 - 1; y <= kN / 2; ++y)
      for (int z = kN / 2 - 1; z <= kN / 2; ++z) v.at(x, y, z) = 0.8f;
  return v;
}

GaussianParams gaussian_at(const Eigen::Vector3d& p, double a) {
  GaussianParams g;
  g.mean = {static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z())};
  g.log_scale = {std::log(0.05f), std::log(0.05f), std::log(0.05f)};
  g.intensity_logit = static_cast<float>(std::log(a / (1.0 - a)));
  return g;
}

TEST(Halo, NoiseIsThreeRobustSigmasOfTheBackgroundAndAtLeastTheFloor) {
  EXPECT_NEAR(stack_noise(neurite_in_noise(0.01)), 0.03, 0.004);
  EXPECT_NEAR(stack_noise(neurite_in_noise(0.03)), 0.09, 0.012);
  EXPECT_EQ(stack_noise(neurite_in_noise(0.0)), kHaloMinNoise);  // a zeroed background has none to measure
}

TEST(Halo, AGaussianBrighterThanTheStackAtItsCentreIsCountedANeuriteOneIsNot) {
  const io::Volume v = neurite_in_noise(0.01);
  const io::WorldFrame frame(kN, kN, kN, Eigen::Vector3d::Ones());
  const double noise = stack_noise(v);
  const Eigen::Vector3d on_neurite = frame.world_from_index(Eigen::Vector3d(8.0, kN / 2 - 0.5, kN / 2 - 0.5));
  const Eigen::Vector3d in_background = frame.world_from_index(Eigen::Vector3d(8.0, 3.0, 4.0));
  const GaussianMixture mixture({
      gaussian_at(on_neurite, 0.8),     // the neurite: as bright as the stack there
      gaussian_at(in_background, 0.3),  // a halo: 0.25 above the background
      gaussian_at(in_background, 0.06),  // dim, within the noise of the background
      gaussian_at(on_neurite, 0.95),    // brighter than the neurite by more than the noise
  });
  const HaloCount c = count_halos(mixture, v, frame, noise);
  EXPECT_EQ(c.gaussians, 4u);
  EXPECT_EQ(c.halos, 2u);
  EXPECT_EQ(c.which, (std::vector<std::size_t>{1, 3}));
  EXPECT_DOUBLE_EQ(c.share(), 0.5);
  EXPECT_EQ(c.noise, noise);
  // Outside the box the stack is 0: any Gaussian above the noise there is a halo.
  const GaussianMixture outside({gaussian_at(Eigen::Vector3d(1.5, 0.0, 0.0), 0.1)});
  EXPECT_EQ(count_halos(outside, v, frame, noise).halos, 1u);
}

}  // namespace
}  // namespace hisnegs::gmf
