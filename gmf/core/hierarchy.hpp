// SPDX-License-Identifier: Apache-2.0
// A level-of-detail hierarchy of a mixture for MIPs seen from afar: an octree over
// the Gaussians' centres whose leaves hold the model's own Gaussians (at most
// `page` each) and whose inner nodes each hold a coarser mixture (at most `page`
// Gaussians) standing for their whole subtree as a MIP sees it from a distance.
// A viewer draws, per node on screen, either the node's own mixture or its
// children's, by the node's `feature` projected to pixels (splat/lod.hpp). The
// merge rule and its measurement: docs/benchmarks.md "Level of detail".
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <span>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"

namespace hisnegs::gmf {

struct HierarchyOptions {
  int page = 4096;  // most Gaussians a node holds, [64, 10^6]
  // How a cluster's Gaussians become one: peak = their brightest peak (a MIP from
  // afar shows the brightest of what a pixel covers), or the mass-weighted mean
  // peak (what a sum would show); the centre and covariance are moment-matched
  // (mass a·s0·s1·s2) either way.
  enum class Peak { kMax, kMean };
  Peak peak = Peak::kMax;
  // The merged Gaussians' largest axis ratio (a cluster along a neurite is long).
  double max_axis_ratio = 64.0;
  void validate() const;
};

struct HierarchyNode {
  std::array<double, 3> lo{}, hi{};  // the octree cell, world units
  int level = 0;                     // 0: the root
  std::array<std::int32_t, 8> children{-1, -1, -1, -1, -1, -1, -1, -1};  // node indices, -1: none
  std::size_t first = 0, count = 0;  // its Gaussians: Hierarchy::gaussians[first, first + count)
  // World size of the detail the node's own mixture leaves out: twice the median
  // longest σ of its merged Gaussians, at least the edge of the cells its subtree
  // was merged in (0 for a leaf, which is the model itself).
  double feature = 0.0;
  [[nodiscard]] bool leaf() const { return children[0] < 0 && children[1] < 0 && children[2] < 0 &&
                                           children[3] < 0 && children[4] < 0 && children[5] < 0 &&
                                           children[6] < 0 && children[7] < 0; }
};

struct Hierarchy {
  std::vector<HierarchyNode> nodes;  // nodes[0] is the root (none for an empty model)
  GaussianMixture gaussians;         // every node's, node after node
  std::size_t model_gaussians = 0;   // K of the model: the leaves' total
  [[nodiscard]] int depth() const;   // levels below the root
};

// The hierarchy of `model` (bounded memory: about twice the model).
[[nodiscard]] Hierarchy build_hierarchy(const GaussianMixture& model, const HierarchyOptions& options = {});

// One Gaussian standing for `members` (not empty) as `options.peak` says.
[[nodiscard]] GaussianParams merge_for_mip(std::span<const GaussianParams> members, const HierarchyOptions& options);

}  // namespace hisnegs::gmf
