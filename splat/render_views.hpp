// SPDX-License-Identifier: Apache-2.0
// Renders every view of a camera set from a mixture with a SplatRenderer, with
// per-view timings and counters: what `render`, `eval` and the benchmarks share.
// Writing files is the caller's.
#pragma once

#include <functional>
#include <span>
#include <vector>

#include "splat/background_floor.hpp"
#include "splat/ground_truth.hpp"
#include "splat/splat_renderer.hpp"

namespace hisnegs::splat {

struct RenderedViews {
  MipStack stack;                      // the images (same layout as ground truth)
  std::vector<SplatFrameStats> stats;  // per view
};

// `params` is 11 K floats (flat_params). `progress(done, total)` after each view.
// `floors` (the model's background, splat/background_floor.hpp) are drawn under the
// Gaussians when not none(); settings.floor is ignored (set per view).
RenderedViews render_views(SplatRenderer& renderer, std::span<const float> params, const CameraSet& cameras,
                           const SplatSettings& settings, const std::function<void(int, int)>& progress = {},
                           const BackgroundFloors& floors = {});

// A 360° orbit of `frames` views at `elevation_deg` (azimuths evenly spaced from 0),
// radius and intrinsics from `options`; views named orbit_000...
CameraSet turntable(const CameraOptions& options, int frames, double elevation_deg);

}  // namespace hisnegs::splat
