// SPDX-License-Identifier: Apache-2.0
// Level of detail for a camera: which nodes of a gmf::Hierarchy a view draws. A
// node is refined (its children drawn instead of its own mixture) while the detail
// its mixture leaves out (HierarchyNode::feature) projects to more than `pixels`
// at the node's nearest point, largest first, within a Gaussian budget. The
// same selection for `render --lod`, `eval --lod` and the viewer.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "gmf/core/hierarchy.hpp"
#include "splat/camera.hpp"
#include "splat/render_views.hpp"

namespace hisnegs::splat {

struct LodOptions {
  double pixels = 1.0;      // the most a left-out detail may project to, > 0
  std::size_t budget = 0;   // the most Gaussians drawn per view; 0: no limit
  void validate() const;    // io::InputError naming --lod and its value
};

struct LodSelection {
  std::vector<std::int32_t> nodes;  // drawn, each its own mixture
  std::size_t gaussians = 0;        // their total
  int deepest = 0;                  // the deepest level drawn
};

// The nodes `view` draws (every node of an empty hierarchy: none).
[[nodiscard]] LodSelection select_lod(const gmf::Hierarchy& h, const Intrinsics& k, const CameraView& view,
                                      const LodOptions& options);

// The flat parameters (flat_params layout) of the selected nodes' Gaussians.
[[nodiscard]] std::vector<float> lod_params(const gmf::Hierarchy& h, const LodSelection& s);

// render_views, each view drawing its own selection; `drawn` gets each view's K.
RenderedViews render_views_lod(SplatRenderer& renderer, const gmf::Hierarchy& h, const CameraSet& cameras,
                               const SplatSettings& settings, const LodOptions& lod, const BackgroundFloors& floors,
                               std::vector<std::size_t>* drawn = nullptr);

}  // namespace hisnegs::splat
