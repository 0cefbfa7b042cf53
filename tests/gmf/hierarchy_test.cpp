// SPDX-License-Identifier: Apache-2.0
// gmf/core/hierarchy: the merge rule (moment-matched centre and covariance, the
// brightest peak or the mass-weighted mean one, an axis-ratio bound) and the
// octree (every model Gaussian in exactly one leaf, at most a page per node,
// children inside their parent, inner nodes coarser than the model).
#include "gmf/core/hierarchy.hpp"

#include "gmf/core/hierarchy_file.hpp"
#include "io/error.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <map>
#include <random>
#include <tuple>

namespace hisnegs::gmf {
namespace {

GaussianParams gaussian(double x, double y, double z, double sigma, double a) {
  GaussianParams g;
  g.mean = {static_cast<float>(x), static_cast<float>(y), static_cast<float>(z)};
  g.log_scale.fill(static_cast<float>(std::log(sigma)));
  g.intensity_logit = static_cast<float>(std::log(a / (1.0 - a)));
  return g;
}

TEST(Hierarchy, OneGaussianMergesIntoItself) {
  const GaussianParams g = gaussian(0.1, -0.2, 0.3, 0.05, 0.7);
  const GaussianParams m = merge_for_mip(std::span<const GaussianParams>(&g, 1), {});
  EXPECT_EQ(m.mean, g.mean);
  EXPECT_EQ(m.log_scale, g.log_scale);
  EXPECT_EQ(m.intensity_logit, g.intensity_logit);
}

// Two equal isotropic Gaussians at ±d on x: centre 0, Σ = diag(s² + d², s², s²),
// peak the brighter one's (max) or their mass-weighted mean.
TEST(Hierarchy, TheMergeMatchesMomentsAndKeepsTheBrightestPeak) {
  const double d = 0.1, s = 0.02;
  const std::vector<GaussianParams> two{gaussian(-d, 0, 0, s, 0.8), gaussian(d, 0, 0, s, 0.8)};
  const GaussianParams m = merge_for_mip(two, {});
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(m.mean[a], 0.0, 1e-7);
  const Eigen::Matrix3d sigma = covariance(m);
  EXPECT_NEAR(sigma(0, 0), s * s + d * d, 1e-6);
  EXPECT_NEAR(sigma(1, 1), s * s, 1e-7);
  EXPECT_NEAR(sigma(2, 2), s * s, 1e-7);
  EXPECT_NEAR(intensity(m), 0.8, 1e-6);
  // Unequal peaks: max takes the brighter, mean lies between.
  const std::vector<GaussianParams> uneven{gaussian(-d, 0, 0, s, 0.9), gaussian(d, 0, 0, s, 0.3)};
  HierarchyOptions mean;
  mean.peak = HierarchyOptions::Peak::kMean;
  EXPECT_NEAR(intensity(merge_for_mip(uneven, {})), 0.9, 1e-6);
  const double between = intensity(merge_for_mip(uneven, mean));
  EXPECT_NEAR(between, (0.9 * 0.9 + 0.3 * 0.3) / 1.2, 1e-6);  // masses a·s³ with one s
  // The axis-ratio bound: far apart, thin.
  HierarchyOptions bounded;
  bounded.max_axis_ratio = 4.0;
  const std::vector<GaussianParams> far{gaussian(-1, 0, 0, 1e-3, 0.5), gaussian(1, 0, 0, 1e-3, 0.5)};
  const GaussianParams b = merge_for_mip(far, bounded);
  const auto [lo, hi] = std::minmax_element(b.log_scale.begin(), b.log_scale.end());
  EXPECT_NEAR(std::exp(*hi - *lo), 4.0, 1e-4);
}

TEST(Hierarchy, EveryGaussianIsInOneLeafAndNodesHoldAPageAtMost) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  GaussianMixture model;
  for (int k = 0; k < 5000; ++k) {  // a dense clump and a sparse spread
    const double f = k < 3000 ? 0.1 : 1.0;
    model.push_back(gaussian(f * u(rng), f * u(rng), 0.3 * f * u(rng), 0.01, 0.2 + 0.3 * (u(rng) + 1.0)));
  }
  HierarchyOptions o;
  o.page = 256;
  const Hierarchy h = build_hierarchy(model, o);
  ASSERT_FALSE(h.nodes.empty());
  EXPECT_EQ(h.model_gaussians, model.size());
  EXPECT_GE(h.depth(), 2);
  std::map<std::tuple<float, float, float, float>, int> leaves;
  for (const HierarchyNode& n : h.nodes) {
    EXPECT_LE(n.count, static_cast<std::size_t>(o.page));
    for (const std::int32_t c : n.children) {
      if (c < 0) continue;
      const HierarchyNode& child = h.nodes[static_cast<std::size_t>(c)];
      EXPECT_EQ(child.level, n.level + 1);
      for (std::size_t a = 0; a < 3; ++a) {
        EXPECT_GE(child.lo[a], n.lo[a]);
        EXPECT_LE(child.hi[a], n.hi[a]);
      }
    }
    if (!n.leaf()) {
      EXPECT_GT(n.feature, 0.0);
      EXPECT_GT(n.count, 0u);
      continue;
    }
    EXPECT_EQ(n.feature, 0.0);
    for (std::size_t k = n.first; k < n.first + n.count; ++k) {
      const GaussianParams& g = h.gaussians[k];
      ++leaves[{g.mean[0], g.mean[1], g.mean[2], g.intensity_logit}];
    }
  }
  std::map<std::tuple<float, float, float, float>, int> all;
  for (const GaussianParams& g : model) ++all[{g.mean[0], g.mean[1], g.mean[2], g.intensity_logit}];
  EXPECT_EQ(leaves, all);
  // A model of one page is its own root.
  GaussianMixture small;
  for (int k = 0; k < 10; ++k) small.push_back(model[static_cast<std::size_t>(k)]);
  const Hierarchy one = build_hierarchy(small, o);
  ASSERT_EQ(one.nodes.size(), 1u);
  EXPECT_TRUE(one.nodes[0].leaf());
  EXPECT_TRUE(build_hierarchy(GaussianMixture{}, o).nodes.empty());
  o.page = 10;
  EXPECT_THROW((void)build_hierarchy(small, o), std::invalid_argument);
}

GaussianMixture spread(int count) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  GaussianMixture model;
  for (int k = 0; k < count; ++k) model.push_back(gaussian(u(rng), u(rng), 0.3 * u(rng), 0.02, 0.5 + 0.4 * u(rng)));
  return model;
}

// The .hgw file: its index gives back the tree, each page its node's Gaussians
// within the compact bounds, the model (its leaves) reads back through
// load_hierarchy_model with the root page's metadata; damage is one line.
TEST(HierarchyFile, RoundTripsTheTreeAndEveryPage) {
  HierarchyOptions o;
  o.page = 100;
  const Hierarchy h = build_hierarchy(spread(700), o);
  ASSERT_GE(h.depth(), 1);
  CheckpointMeta meta;
  meta.extra.emplace_back("source", "a test");
  const std::string bytes = encode_hierarchy_file(h, meta);
  ASSERT_TRUE(has_hierarchy_magic(bytes));
  const HierarchyIndex index = read_hierarchy_index(bytes, bytes.size(), "t.hgw");
  ASSERT_EQ(index.tree.nodes.size(), h.nodes.size());
  EXPECT_EQ(index.tree.model_gaussians, 700u);
  for (std::size_t i = 0; i < h.nodes.size(); ++i) {
    const HierarchyNode &a = h.nodes[i], &b = index.tree.nodes[i];
    EXPECT_EQ(a.children, b.children);
    EXPECT_EQ(a.count, b.count);
    EXPECT_EQ(a.level, b.level);
    EXPECT_EQ(a.lo, b.lo);
    EXPECT_EQ(a.feature, b.feature);
    const Checkpoint page = read_hierarchy_page(bytes, index, i, "t.hgw");
    ASSERT_EQ(page.mixture.size(), a.count);
    // Stored in Morton order: every centre has its original within the position bound.
    for (const GaussianParams& g : page.mixture) {
      double nearest = 1e9;
      for (std::size_t k = a.first; k < a.first + a.count; ++k) {
        const GaussianParams& o2 = h.gaussians[k];
        nearest = std::min<double>(nearest, std::abs(g.mean[0] - o2.mean[0]) + std::abs(g.mean[1] - o2.mean[1]) +
                                        std::abs(g.mean[2] - o2.mean[2]));
      }
      EXPECT_LT(nearest, 1e-3);
    }
  }
  // Damage: the index's CRC, a page's byte, a child before its parent.
  std::string broken = bytes;
  broken[kHierarchyHeadBytes + 5] ^= 0x01;
  EXPECT_THROW((void)read_hierarchy_index(broken, broken.size(), "t.hgw"), io::InputError);
  broken = bytes;
  broken[index.offset[1] + 40] ^= 0x01;
  const HierarchyIndex again = read_hierarchy_index(broken, broken.size(), "t.hgw");
  EXPECT_THROW((void)read_hierarchy_page(broken, again, 1, "t.hgw"), io::InputError);
  // A tree: the root naming its first child twice (its second child then has no parent).
  {
    std::string twice = bytes;
    const std::size_t list = twice.find("\"children\":[") + 12;
    const std::size_t end = twice.find(']', list);
    std::vector<std::string> ids;
    for (std::size_t at = list; at < end;) {
      const std::size_t comma = std::min(twice.find(',', at), end);
      ids.push_back(twice.substr(at, comma - at));
      at = comma + 1;
    }
    std::vector<std::string> real;
    for (const std::string& id : ids) {
      if (id != "-1") real.push_back(id);
    }
    ASSERT_GE(real.size(), 2u);
    ASSERT_EQ(real[0].size(), real[1].size());
    std::string replaced;
    for (std::size_t c = 0; c < ids.size(); ++c) replaced += (c ? "," : "") + (ids[c] == real[1] ? real[0] : ids[c]);
    twice.replace(list, end - list, replaced);
    const std::uint32_t crc = crc32_of(std::string_view(twice).substr(0, index.index_end - 4));
    std::memcpy(twice.data() + index.index_end - 4, &crc, 4);
    try {
      (void)read_hierarchy_index(twice, twice.size(), "t.hgw");
      ADD_FAILURE() << "a node with two parents was read";
    } catch (const io::InputError& e) {
      EXPECT_NE(std::string(e.what()).find("has two parents"), std::string::npos) << e.what();
    }
  }
  EXPECT_THROW((void)read_hierarchy_index(bytes.substr(0, 20), bytes.size(), "t.hgw"), io::InputError);
  EXPECT_THROW((void)read_hierarchy_index(bytes, index.index_end - 1, "t.hgw"), io::InputError);
  try {
    (void)read_hierarchy_index(bytes, bytes.size() - 10, "t.hgw");  // the last page runs past it
    ADD_FAILURE() << "a file shorter than its index said";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("t.hgw: hierarchy:"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace hisnegs::gmf
