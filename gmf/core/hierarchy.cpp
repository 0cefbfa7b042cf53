// SPDX-License-Identifier: Apache-2.0
// The octree of gmf/core/hierarchy.hpp: built top-down by splitting the centres at
// the cell's middle; an inner node's mixture clusters its whole subtree's
// Gaussians on the finest grid over the cell that leaves at most `page` occupied
// cells, one merged Gaussian per cell.
#include "gmf/core/hierarchy.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>
#include <unordered_map>

#include "gmf/core/density_ops.hpp"

namespace hisnegs::gmf {
namespace {

constexpr int kMostLevels = 21;  // 2^21 cells per axis: below float resolution of a unit box

struct Builder {
  const GaussianMixture& model;
  const HierarchyOptions& options;
  Hierarchy out;

  [[nodiscard]] Eigen::Vector3d centre(std::uint32_t k) const {
    const GaussianParams& g = model[k];
    return {g.mean[0], g.mean[1], g.mean[2]};
  }

  // Cells of `n` per axis over [lo, lo + edge): the occupied cells' members.
  [[nodiscard]] std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> cells(
      const std::vector<std::uint32_t>& members, const Eigen::Vector3d& lo, double edge, std::uint64_t n) const {
    std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> map;
    const double per = static_cast<double>(n) / edge;
    for (const std::uint32_t k : members) {
      const Eigen::Vector3d p = (centre(k) - lo) * per;
      std::uint64_t key = 0;
      for (int a = 0; a < 3; ++a) {
        const auto i = static_cast<std::uint64_t>(std::clamp(std::floor(p[a]), 0.0, static_cast<double>(n - 1)));
        key = key * n + i;
      }
      map[key].push_back(k);
    }
    return map;
  }

  // The node's own mixture: the finest grid (a power of two per axis) whose
  // occupied cells are at most `page`, one merged Gaussian per cell.
  void merge_node(HierarchyNode& node, const std::vector<std::uint32_t>& members) {
    const Eigen::Vector3d lo(node.lo[0], node.lo[1], node.lo[2]);
    const double edge = node.hi[0] - node.lo[0];
    std::uint64_t n = 1;
    auto best = cells(members, lo, edge, n);
    for (int level = 1; level <= kMostLevels; ++level) {
      auto finer = cells(members, lo, edge, n * 2);
      if (finer.size() > static_cast<std::size_t>(options.page)) break;
      n *= 2;
      best = std::move(finer);
      if (best.size() == members.size()) break;  // every Gaussian alone in its cell
    }
    // A deterministic order: by cell key.
    std::vector<std::uint64_t> keys;
    keys.reserve(best.size());
    for (const auto& [key, ks] : best) keys.push_back(key);
    std::sort(keys.begin(), keys.end());
    node.first = out.gaussians.size();
    std::vector<GaussianParams> group;
    for (const std::uint64_t key : keys) {
      group.clear();
      for (const std::uint32_t k : best[key]) group.push_back(model[k]);
      out.gaussians.push_back(merge_for_mip(group, options));
    }
    node.count = keys.size();
    // The detail it leaves out: what a typical merged Gaussian spreads a peak over
    // (twice the median longest σ), at least the cell it merged.
    std::vector<float> longest;
    longest.reserve(node.count);
    for (std::size_t k = node.first; k < out.gaussians.size(); ++k) {
      const GaussianParams& g = out.gaussians[k];
      longest.push_back(g.log_scale[static_cast<std::size_t>(longest_axis(g))]);
    }
    std::nth_element(longest.begin(), longest.begin() + static_cast<std::ptrdiff_t>(longest.size() / 2), longest.end());
    node.feature = std::max(edge / static_cast<double>(n),
                            2.0 * std::exp(static_cast<double>(longest[longest.size() / 2])));
  }

  // Builds the node `index` (its cell set) over `members`.
  void build(std::size_t index, std::vector<std::uint32_t> members) {
    const int level = out.nodes[index].level;
    if (members.size() <= static_cast<std::size_t>(options.page) || level >= kMostLevels) {
      HierarchyNode& leaf = out.nodes[index];
      leaf.first = out.gaussians.size();
      for (const std::uint32_t k : members) out.gaussians.push_back(model[k]);
      leaf.count = members.size();
      out.model_gaussians += members.size();
      return;
    }
    std::array<std::vector<std::uint32_t>, 8> parts;
    const HierarchyNode cell = out.nodes[index];
    const Eigen::Vector3d mid = (Eigen::Vector3d(cell.lo[0], cell.lo[1], cell.lo[2]) +
                                 Eigen::Vector3d(cell.hi[0], cell.hi[1], cell.hi[2])) / 2.0;
    for (const std::uint32_t k : members) {
      const Eigen::Vector3d p = centre(k);
      parts[static_cast<std::size_t>((p.x() >= mid.x() ? 1 : 0) | (p.y() >= mid.y() ? 2 : 0) |
                                     (p.z() >= mid.z() ? 4 : 0))]
          .push_back(k);
    }
    merge_node(out.nodes[index], members);
    members = {};
    for (int o = 0; o < 8; ++o) {
      if (parts[static_cast<std::size_t>(o)].empty()) continue;
      HierarchyNode child;
      child.level = level + 1;
      for (int a = 0; a < 3; ++a) {
        const bool upper = ((o >> a) & 1) != 0;
        child.lo[static_cast<std::size_t>(a)] = upper ? mid[a] : cell.lo[static_cast<std::size_t>(a)];
        child.hi[static_cast<std::size_t>(a)] = upper ? cell.hi[static_cast<std::size_t>(a)] : mid[a];
      }
      const auto at = static_cast<std::int32_t>(out.nodes.size());
      out.nodes.push_back(child);
      out.nodes[index].children[static_cast<std::size_t>(o)] = at;
      build(static_cast<std::size_t>(at), std::move(parts[static_cast<std::size_t>(o)]));
    }
  }
};

}  // namespace

void HierarchyOptions::validate() const {
  if (page < 64 || page > 1000000) {
    throw std::invalid_argument("hierarchy page = " + std::to_string(page) + " is outside [64, 10^6]");
  }
  if (!(max_axis_ratio >= 1.0) || !std::isfinite(max_axis_ratio)) {
    throw std::invalid_argument("hierarchy max_axis_ratio must be a finite number >= 1");
  }
}

int Hierarchy::depth() const {
  int d = 0;
  for (const HierarchyNode& n : nodes) d = std::max(d, n.level);
  return d;
}

GaussianParams merge_for_mip(std::span<const GaussianParams> members, const HierarchyOptions& options) {
  if (members.empty()) throw std::invalid_argument("merge_for_mip: no Gaussians to merge");
  if (members.size() == 1) return members[0];
  double total = 0.0, peak_max = 0.0, peak_mean = 0.0;
  Eigen::Vector3d mu = Eigen::Vector3d::Zero();
  std::vector<double> mass(members.size());
  for (std::size_t k = 0; k < members.size(); ++k) {
    const GaussianParams& g = members[k];
    const double a = intensity(g);
    const Eigen::Vector3d s = scales(g);
    mass[k] = std::max(1e-30, a * s.prod());
    total += mass[k];
    peak_max = std::max(peak_max, a);
    peak_mean += mass[k] * a;
    mu += mass[k] * Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2]);
  }
  mu /= total;
  peak_mean /= total;
  Eigen::Matrix3d sigma = Eigen::Matrix3d::Zero();
  for (std::size_t k = 0; k < members.size(); ++k) {
    const GaussianParams& g = members[k];
    const Eigen::Vector3d d = Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2]) - mu;
    sigma += mass[k] * (covariance(g) + d * d.transpose());
  }
  sigma /= total;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(sigma);
  Eigen::Matrix3d axes = eig.eigenvectors();
  if (axes.determinant() < 0) axes.col(0) = -axes.col(0);
  const Eigen::Vector3d& lambda = eig.eigenvalues();  // ascending
  const double longest = std::sqrt(std::max(lambda[2], 1e-30));
  GaussianParams out;
  for (int a = 0; a < 3; ++a) {
    const double s = std::max(std::sqrt(std::max(lambda[a], 0.0)), longest / options.max_axis_ratio);
    out.log_scale[static_cast<std::size_t>(a)] = static_cast<float>(std::log(s));
    out.mean[static_cast<std::size_t>(a)] = static_cast<float>(mu[a]);
  }
  const Eigen::Quaterniond q(axes);
  out.rotation = {static_cast<float>(q.w()), static_cast<float>(q.x()), static_cast<float>(q.y()),
                  static_cast<float>(q.z())};
  const double peak = options.peak == HierarchyOptions::Peak::kMax ? peak_max : peak_mean;
  out.intensity_logit = static_cast<float>(logit(std::clamp(peak, 1e-6, 1.0 - 1e-6)));
  return out;
}

Hierarchy build_hierarchy(const GaussianMixture& model, const HierarchyOptions& options) {
  options.validate();
  Builder b{model, options, {}};
  if (model.empty()) return std::move(b.out);
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e300), hi = Eigen::Vector3d::Constant(-1e300);
  for (std::uint32_t k = 0; k < model.size(); ++k) {
    lo = lo.cwiseMin(b.centre(k));
    hi = hi.cwiseMax(b.centre(k));
  }
  // A cube (cells of one size per level), a little larger than the centres' box.
  const double edge = std::max((hi - lo).maxCoeff(), 1e-6) * (1.0 + 1e-6);
  const Eigen::Vector3d mid = (lo + hi) / 2.0;
  HierarchyNode root;
  for (int a = 0; a < 3; ++a) {
    root.lo[static_cast<std::size_t>(a)] = mid[a] - edge / 2.0;
    root.hi[static_cast<std::size_t>(a)] = mid[a] + edge / 2.0;
  }
  b.out.nodes.push_back(root);
  std::vector<std::uint32_t> all(model.size());
  for (std::uint32_t k = 0; k < model.size(); ++k) all[k] = k;
  b.build(0, std::move(all));
  return std::move(b.out);
}

}  // namespace hisnegs::gmf
