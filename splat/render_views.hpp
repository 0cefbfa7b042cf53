// SPDX-License-Identifier: Apache-2.0
// Renders every view of a camera set from a mixture with a SplatRenderer, with
// per-view timings and counters: what `render`, `eval` and the benchmarks share.
// Writing files is the caller's.
#pragma once

#include <functional>
#include <limits>
#include <span>
#include <vector>

#include "splat/background_floor.hpp"
#include "splat/ground_truth.hpp"
#include "splat/splat_renderer.hpp"

namespace hisnegs::splat {

// One pixel's soft-MIP state (SplatRenderer::soft_state) and its value I = W / S.
struct SoftPixel {
  float m = -std::numeric_limits<float>::infinity();
  float S = 0;
  float I = 0;
};

// The state of the union of two disjoint sets of Gaussians from each set's (the
// online softmax's merge, in double). Exact up to rounding but for the terms that
// skip_log_weight skips: a set may keep a term its union skips (below the union's
// largest by more than the threshold: a relative weight < e^-threshold).
[[nodiscard]] SoftPixel merge_soft_pixel(SoftPixel a, SoftPixel b);

// Several processes, each rendering a share of one model's Gaussians (the MPI render
// of apps/pipeline/distributed.hpp): the combination that makes this process's image
// of its share the image of the whole model, on the process that keeps the images.
class ShareCombiner {
 public:
  virtual ~ShareCombiner() = default;
  // Hard MIP: the element-wise max over the shares (exact: bit-identical to one render).
  virtual void max(std::span<float> image) const = 0;
  // Soft MIP: merge_soft_pixel over the shares, pixel by pixel.
  virtual void merge_soft(std::span<SoftPixel> pixels) const = 0;
};

struct RenderedViews {
  MipStack stack;                      // the images (same layout as ground truth)
  std::vector<SplatFrameStats> stats;  // per view
};

// `params` is 11 K floats (flat_params). `progress(done, total)` after each view.
// `floors` (the model's background, splat/background_floor.hpp) are drawn under the
// Gaussians when not none(); settings.floor is ignored (set per view). With `shares`,
// `params` is this process's share of the model and each view is combined with the
// other shares' (the floor, a max in both modes, is applied after a soft merge).
RenderedViews render_views(SplatRenderer& renderer, std::span<const float> params, const CameraSet& cameras,
                           const SplatSettings& settings, const std::function<void(int, int)>& progress = {},
                           const BackgroundFloors& floors = {}, const ShareCombiner* shares = nullptr);

// A 360° orbit of `frames` views at `elevation_deg` (azimuths evenly spaced from 0),
// radius and intrinsics from `options`; views named orbit_000...
CameraSet turntable(const CameraOptions& options, int frames, double elevation_deg);

}  // namespace hisnegs::splat
