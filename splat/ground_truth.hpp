// SPDX-License-Identifier: Apache-2.0
// Ground-truth MIP stacks: every view of a camera set ray-marched on the chosen
// back end (TBB or CUDA), with per-view timings. Writing files is the caller's.
#pragma once

#include <functional>
#include <span>
#include <vector>

#include "io/volume.hpp"
#include "splat/backend.hpp"
#include "splat/camera.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::splat {

struct MipStack {
  int width = 0, height = 0, views = 0;
  std::vector<float> pixels;             // views × height × width, view-major
  std::vector<double> seconds_per_view;  // wall clock of each view's render
  Backend backend = Backend::kCpu;

  [[nodiscard]] std::span<const float> view(int i) const {
    return {pixels.data() + static_cast<std::size_t>(i) * width * height, static_cast<std::size_t>(width) * height};
  }
};

// Renders every view of `cameras` from the normalized `volume`. `progress(done, total)`
// is called after each view. Throws io::InputError for invalid options.
MipStack render_ground_truth(const io::Volume& volume, const io::WorldFrame& frame, const CameraSet& cameras,
                             const RaymarchOptions& options, Backend backend,
                             const std::function<void(int, int)>& progress = {});

}  // namespace hisnegs::splat
