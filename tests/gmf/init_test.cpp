// SPDX-License-Identifier: Apache-2.0
// gmf/init: grid initialization meets the Gaussian budget on the foreground and
// puts each Gaussian at its cell's intensity-weighted centroid, with the cell's
// mean value as intensity and half a grid step as σ.
#include "gmf/init.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>

#include "gmf/core/gaussian_mixture.hpp"
#include "io/error.hpp"
#include "tests/gmf/gmf_test_scenes.hpp"

namespace hisnegs::gmf {
namespace {

io::Volume zeros(int nx, int ny, int nz) {
  io::Volume v;
  v.nx = nx;
  v.ny = ny;
  v.nz = nz;
  v.voxels.assign(v.size(), 0.0f);
  v.source = "hand-made";
  v.normalization.method = io::NormalizationMethod::kMinMax;
  return v;
}

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

// Three foreground voxels of different brightness and a budget of one: a single
// Gaussian at Σ v p / Σ v (not the brightest voxel, not the plain mean), with
// a = the cell's mean value (not its maximum). Voxels below the threshold do
// not count.
TEST(GmfInit, PlacesTheGaussianAtTheIntensityWeightedCentroid) {
  io::Volume v = zeros(16, 16, 16);
  const io::WorldFrame frame(16, 16, 16, Eigen::Vector3d::Ones());
  // All in the +x +y +z octant of the world box.
  const std::array<std::array<int, 3>, 3> fg = {{{10, 10, 10}, {11, 10, 10}, {11, 12, 10}}};
  const std::array<float, 3> value = {0.2f, 0.4f, 0.8f};
  for (int i = 0; i < 3; ++i) v.at(fg[i][0], fg[i][1], fg[i][2]) = value[i];
  v.at(3, 3, 3) = 0.09f;      // below the threshold
  v.at(13, 9, 12) = 0.0999f;  // just below it
  InitReport report;
  const GaussianMixture m = initialize_on_grid(v, frame, 0.1, 1, &report);
  ASSERT_EQ(m.size(), 1u);
  EXPECT_EQ(report.foreground, 3);
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  double vsum = 0;
  for (int i = 0; i < 3; ++i) {
    centroid += double(value[i]) * frame.world_from_index(Eigen::Vector3d(fg[i][0], fg[i][1], fg[i][2]));
    vsum += value[i];
  }
  centroid /= vsum;
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(m[0].mean[a], centroid[a], 1e-6) << "axis " << a;
  EXPECT_NEAR(intensity(m[0]), vsum / 3.0, 1e-6);
  // σ = half a grid step, at least half a voxel; axis-aligned.
  const double sigma = std::max(0.5 * frame.voxel_size().x(), 0.5 * report.cell_world);
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(m[0].log_scale[a], std::log(sigma), 1e-6);
  EXPECT_EQ(m[0].rotation, (std::array<float, 4>{1, 0, 0, 0}));
}

// On the scene, every Gaussian sits at the intensity-weighted centroid of the
// foreground voxels of its cell (world grid of step report.cell_world anchored
// at the world origin) and carries their mean value; one Gaussian per occupied
// cell, in cell order.
TEST(GmfInit, EveryGaussianIsItsCellsWeightedCentroid) {
  const Scene scene = make_scene(3);
  constexpr double kThreshold = 0.1;
  InitReport report;
  const GaussianMixture m = initialize_on_grid(scene.volume, scene.frame, kThreshold, 60, &report);
  ASSERT_GT(report.cell_world, 0.0);
  struct Sum {
    Eigen::Vector3d weighted = Eigen::Vector3d::Zero();
    double v = 0;
    int count = 0;
  };
  std::map<std::array<long, 3>, Sum> cells;  // lexicographic (x, y, z) order
  for (int z = 0; z < scene.volume.nz; ++z)
    for (int y = 0; y < scene.volume.ny; ++y)
      for (int x = 0; x < scene.volume.nx; ++x) {
        const float v = scene.volume.at(x, y, z);
        if (!(v > kThreshold)) continue;
        const Eigen::Vector3d p = scene.frame.world_from_index(Eigen::Vector3d(x, y, z));
        std::array<long, 3> key;
        for (int a = 0; a < 3; ++a) key[a] = static_cast<long>(std::floor(p[a] / report.cell_world));
        Sum& s = cells[key];
        s.weighted += double(v) * p;
        s.v += v;
        ++s.count;
      }
  ASSERT_EQ(m.size(), cells.size());
  std::size_t k = 0;
  for (const auto& [key, s] : cells) {
    const Eigen::Vector3d c = s.weighted / s.v;
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(m[k].mean[a], c[a], 1e-6) << "gaussian " << k;
    EXPECT_NEAR(intensity(m[k]), std::clamp(s.v / s.count, 0.02, 0.98), 1e-6) << "gaussian " << k;
    ++k;
  }
}

// A foreground of 2³ voxels around the centre of the stack straddles all three
// coordinate planes, so origin-anchored cells never hold it in fewer than 8;
// every budget from 1 up is still met.
TEST(GmfInit, MeetsSmallBudgetsForAForegroundAroundTheCentre) {
  io::Volume v = zeros(16, 16, 16);
  for (int z = 7; z <= 8; ++z)
    for (int y = 7; y <= 8; ++y)
      for (int x = 7; x <= 8; ++x) v.at(x, y, z) = 0.5f;
  const io::WorldFrame frame(16, 16, 16, Eigen::Vector3d::Ones());
  for (int budget = 1; budget <= 9; ++budget) {
    const GaussianMixture m = initialize_on_grid(v, frame, 0.1, budget);
    EXPECT_LE(m.size(), static_cast<std::size_t>(budget)) << "budget " << budget;
    EXPECT_GE(m.size(), 1u);
  }
  // Budget 1: one Gaussian at the centre of the eight voxels (the world origin).
  const GaussianMixture one = initialize_on_grid(v, frame, 0.1, 1);
  ASSERT_EQ(one.size(), 1u);
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(one[0].mean[a], 0.0, 1e-6);
}

// The init starts within the fit's largest scale: a budget of one Gaussian on a
// spread foreground makes one cell of the whole box (σ of half of it), which
// initialize_mixture caps at GmfOptions::largest_scale (a bricked fit's bound, or
// the default), so a fit that runs no round still keeps to it.
TEST(GmfInit, StartsWithinTheFitsLargestScale) {
  io::Volume v = zeros(32, 32, 32);
  v.at(2, 3, 4) = 0.5f;
  v.at(29, 28, 27) = 0.7f;
  const io::WorldFrame frame(32, 32, 32, Eigen::Vector3d::Ones());
  const double voxel = frame.voxel_size().maxCoeff();
  ASSERT_GT(std::exp(initialize_on_grid(v, frame, 0.1, 1)[0].log_scale[0]), 8.0 * voxel) << "the case must be large";
  for (const double bound : {0.0, 3.0 * voxel}) {
    GmfOptions o;
    o.gaussians = 1;
    o.max_scale_world = bound;
    const GaussianMixture m = initialize_mixture(v, frame, 0.1, o);
    ASSERT_EQ(m.size(), 1u);
    const double largest = o.largest_scale(frame.voxel_size().minCoeff(), voxel);
    EXPECT_EQ(largest, bound > 0 ? bound : std::min(0.5, 32.0 * voxel));
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(std::exp(m[0].log_scale[a]), largest, 1e-6 * largest) << "bound " << bound;
  }
}

// A warm start keeps the model's Gaussians centred inside the frame's box, the
// brightest `gaussians` of them (in the model's order), with every scale within the
// fit's largest and every axis ratio within max_axis_ratio.
TEST(GmfInit, AWarmStartKeepsTheBrightestInsideWithinTheFitsBounds) {
  const io::WorldFrame frame(32, 32, 16, Eigen::Vector3d(1.0, 1.0, 0.5));
  GaussianMixture model;
  const auto add = [&](float x, float y, float z, float logit, float log_scale) {
    GaussianParams g;
    g.mean = {x, y, z};
    g.log_scale = {log_scale, log_scale, log_scale};
    g.intensity_logit = logit;
    model.push_back(g);
  };
  add(0.0f, 0.0f, 0.0f, -1.0f, -3.0f);
  add(0.5f, -0.5f, 0.4f, 2.0f, -3.0f);
  add(0.0f, 0.0f, 0.6f, 5.0f, -3.0f);  // outside: |z| > 0.5
  add(-1.1f, 0.0f, 0.0f, 5.0f, -3.0f); // outside: |x| > 1
  add(-0.9f, 0.9f, -0.5f, 1.0f, 2.0f); // inside, on the face; σ e^2 beyond the largest
  add(0.2f, 0.2f, 0.2f, 0.5f, -3.0f);
  GmfOptions o;
  o.gaussians = 3;
  const GaussianMixture m = warm_start_mixture(model, frame, o);
  ASSERT_EQ(m.size(), 3u);
  EXPECT_EQ(m[0].intensity_logit, 2.0f);
  EXPECT_EQ(m[1].intensity_logit, 1.0f);
  EXPECT_EQ(m[2].intensity_logit, 0.5f);
  const double largest = o.largest_scale(frame.voxel_size().minCoeff(), frame.voxel_size().maxCoeff());
  for (const float s : m[1].log_scale) EXPECT_NEAR(std::exp(s), largest, 1e-6 * largest);
  EXPECT_EQ(m[0].log_scale[0], -3.0f);
  o.gaussians = 100;
  EXPECT_EQ(warm_start_mixture(model, frame, o).size(), 4u);
  // An axis ratio beyond the bound is brought within it.
  model[0].log_scale = {0.0f, -8.0f, -3.0f};
  o.max_axis_ratio = 4.0;
  const GaussianMixture bounded = warm_start_mixture(model, frame, o);
  for (const GaussianParams& g : bounded) {
    const auto [lo, hi] = std::minmax_element(g.log_scale.begin(), g.log_scale.end());
    EXPECT_LE(std::exp(*hi - *lo), 4.0 * (1 + 1e-5));
  }
  // Nothing inside: empty.
  GaussianMixture far;
  far.push_back(model[3]);
  EXPECT_TRUE(warm_start_mixture(far, frame, o).empty());
}

}  // namespace
}  // namespace hisnegs::gmf
