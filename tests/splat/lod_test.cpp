// SPDX-License-Identifier: Apache-2.0
// splat/lod: from far away a view draws the root's coarse mixture; from close by
// the model's own Gaussians; a budget holds; the selection covers the model once.
#include "splat/lod.hpp"

#include <gtest/gtest.h>

#include <random>

#include "io/error.hpp"

namespace hisnegs::splat {
namespace {

gmf::Hierarchy clumps() {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  gmf::GaussianMixture model;
  for (int k = 0; k < 4000; ++k) {
    gmf::GaussianParams g;
    g.mean = {static_cast<float>(u(rng)), static_cast<float>(u(rng)), static_cast<float>(0.2 * u(rng))};
    g.log_scale.fill(std::log(0.01f));
    model.push_back(g);
  }
  gmf::HierarchyOptions o;
  o.page = 128;
  return gmf::build_hierarchy(model, o);
}

// Every model Gaussian's place is covered once: no selected node is an ancestor of another.
void expect_a_cover(const gmf::Hierarchy& h, const LodSelection& s) {
  std::vector<int> parent(h.nodes.size(), -1);
  for (std::size_t n = 0; n < h.nodes.size(); ++n) {
    for (const std::int32_t c : h.nodes[n].children) {
      if (c >= 0) parent[static_cast<std::size_t>(c)] = static_cast<int>(n);
    }
  }
  std::vector<bool> chosen(h.nodes.size(), false);
  for (const std::int32_t id : s.nodes) chosen[static_cast<std::size_t>(id)] = true;
  std::size_t leaves_covered = 0;
  for (std::size_t n = 0; n < h.nodes.size(); ++n) {
    if (!h.nodes[n].leaf()) continue;
    int covered = 0;
    for (int a = static_cast<int>(n); a >= 0; a = parent[static_cast<std::size_t>(a)]) {
      covered += chosen[static_cast<std::size_t>(a)] ? 1 : 0;
    }
    EXPECT_EQ(covered, 1) << "leaf " << n;
    leaves_covered += h.nodes[n].count;
  }
  EXPECT_EQ(leaves_covered, h.model_gaussians);
}

TEST(Lod, FarViewsDrawTheRootAndCloseOnesTheModel) {
  const gmf::Hierarchy h = clumps();
  ASSERT_GE(h.depth(), 2);
  CameraOptions co;
  const Intrinsics k = make_intrinsics(co);
  const LodSelection far = select_lod(h, k, orbit_view(20, 30, 2000.0, "far"), {});
  ASSERT_EQ(far.nodes.size(), 1u);
  EXPECT_EQ(far.nodes[0], 0);
  EXPECT_EQ(far.gaussians, h.nodes[0].count);
  const LodSelection close = select_lod(h, k, orbit_view(20, 30, 2.5, "close"), {1e-6, 0});
  EXPECT_EQ(close.gaussians, h.model_gaussians);
  EXPECT_EQ(close.deepest, h.depth());
  expect_a_cover(h, close);
  const LodSelection mid = select_lod(h, k, orbit_view(20, 30, 40.0, "mid"), {1.0, 0});
  EXPECT_LT(mid.gaussians, h.model_gaussians) << mid.gaussians;
  EXPECT_GT(mid.nodes.size(), 1u) << mid.gaussians;
  expect_a_cover(h, mid);
  std::size_t total = 0;
  for (const std::int32_t id : mid.nodes) total += h.nodes[static_cast<std::size_t>(id)].count;
  EXPECT_EQ(total, mid.gaussians);
  EXPECT_EQ(lod_params(h, mid).size(), mid.gaussians * gmf::kGaussianParamCount);
  // A budget: the largest projected detail is refined first, never past the budget.
  const LodSelection capped = select_lod(h, k, orbit_view(20, 30, 2.5, "capped"), {1e-6, 1000});
  EXPECT_LE(capped.gaussians, 1000u);
  EXPECT_GT(capped.gaussians, h.nodes[0].count);
  expect_a_cover(h, capped);
  EXPECT_THROW((void)select_lod(h, k, orbit_view(20, 30, 2.5, "x"), {0.0, 0}), io::InputError);
}

}  // namespace
}  // namespace hisnegs::splat
