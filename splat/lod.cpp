// SPDX-License-Identifier: Apache-2.0
// select_lod: a max-heap of the drawn nodes by projected feature, refined from the
// root while the largest projects above the limit and the budget holds.
#include "splat/lod.hpp"

#include <algorithm>
#include <cmath>
#include <queue>
#include <utility>

#include "io/error.hpp"

namespace hisnegs::splat {
namespace {

// Pixels that `node`'s left-out detail spans, seen from `centre` (its nearest point:
// infinitely many when the camera is inside the cell).
double projected(const gmf::HierarchyNode& node, const Eigen::Vector3d& centre, double focal, double near) {
  if (node.feature <= 0) return 0.0;
  double d2 = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double lo = node.lo[static_cast<std::size_t>(a)], hi = node.hi[static_cast<std::size_t>(a)];
    const double d = centre[a] < lo ? lo - centre[a] : centre[a] > hi ? centre[a] - hi : 0.0;
    d2 += d * d;
  }
  return node.feature * focal / std::max(std::sqrt(d2), near);
}

}  // namespace

void LodOptions::validate() const {
  if (!(pixels > 0) || !std::isfinite(pixels)) {
    throw io::InputError("--lod = " + io::number_text(pixels) + ": the pixels must be a finite number > 0");
  }
}

LodSelection select_lod(const gmf::Hierarchy& h, const Intrinsics& k, const CameraView& view,
                        const LodOptions& options) {
  options.validate();
  LodSelection s;
  if (h.nodes.empty()) return s;
  const Eigen::Vector3d centre = view.center_world();
  const double focal = std::max(k.fx, k.fy);
  using Entry = std::pair<double, std::int32_t>;
  std::priority_queue<Entry> open;  // drawn nodes that might be refined, largest first
  std::vector<std::int32_t> kept;   // drawn for good
  open.emplace(projected(h.nodes[0], centre, focal, k.near), 0);
  s.gaussians = h.nodes[0].count;
  while (!open.empty()) {
    const auto [pixels, id] = open.top();
    open.pop();
    const gmf::HierarchyNode& node = h.nodes[static_cast<std::size_t>(id)];
    std::size_t children = 0;
    for (const std::int32_t c : node.children) {
      if (c >= 0) children += h.nodes[static_cast<std::size_t>(c)].count;
    }
    const bool fits = options.budget == 0 || s.gaussians - node.count + children <= options.budget;
    if (node.leaf() || pixels <= options.pixels || !fits) {
      kept.push_back(id);
      continue;
    }
    s.gaussians = s.gaussians - node.count + children;
    for (const std::int32_t c : node.children) {
      if (c >= 0) open.emplace(projected(h.nodes[static_cast<std::size_t>(c)], centre, focal, k.near), c);
    }
  }
  std::sort(kept.begin(), kept.end());
  for (const std::int32_t id : kept) s.deepest = std::max(s.deepest, h.nodes[static_cast<std::size_t>(id)].level);
  s.nodes = std::move(kept);
  return s;
}

std::vector<float> lod_params(const gmf::Hierarchy& h, const LodSelection& s) {
  const std::span<const float> all = gmf::flat_params(h.gaussians);
  std::vector<float> out;
  out.reserve(s.gaussians * gmf::kGaussianParamCount);
  for (const std::int32_t id : s.nodes) {
    const gmf::HierarchyNode& n = h.nodes[static_cast<std::size_t>(id)];
    const auto from = all.begin() + static_cast<std::ptrdiff_t>(n.first * gmf::kGaussianParamCount);
    out.insert(out.end(), from, from + static_cast<std::ptrdiff_t>(n.count * gmf::kGaussianParamCount));
  }
  return out;
}

RenderedViews render_views_lod(SplatRenderer& renderer, const gmf::Hierarchy& h, const CameraSet& cameras,
                               const SplatSettings& settings, const LodOptions& lod, const BackgroundFloors& floors,
                               std::vector<std::size_t>* drawn) {
  RenderedViews all;
  all.stack.width = cameras.intrinsics.width;
  all.stack.height = cameras.intrinsics.height;
  for (const CameraView& view : cameras.views) {
    const LodSelection s = select_lod(h, cameras.intrinsics, view, lod);
    const std::vector<float> params = lod_params(h, s);
    CameraSet one{cameras.intrinsics, {view}};
    RenderedViews r = render_views(renderer, params, one, settings, {}, floors);
    all.stack.backend = r.stack.backend;
    all.stack.pixels.insert(all.stack.pixels.end(), r.stack.pixels.begin(), r.stack.pixels.end());
    all.stack.seconds_per_view.insert(all.stack.seconds_per_view.end(), r.stack.seconds_per_view.begin(),
                                      r.stack.seconds_per_view.end());
    all.stats.insert(all.stats.end(), r.stats.begin(), r.stats.end());
    ++all.stack.views;
    if (drawn != nullptr) drawn->push_back(s.gaussians);
  }
  return all;
}

}  // namespace hisnegs::splat
