// SPDX-License-Identifier: Apache-2.0
// render_views: one forward per view into the stack, timed per view; turntable().
#include "splat/render_views.hpp"

#include <cstdio>

#include "io/error.hpp"
#include "io/timer.hpp"

namespace hisnegs::splat {

RenderedViews render_views(SplatRenderer& renderer, std::span<const float> params, const CameraSet& cameras,
                           const SplatSettings& settings, const std::function<void(int, int)>& progress,
                           const BackgroundFloors& floors) {
  RenderedViews out;
  MipStack& s = out.stack;
  s.width = cameras.intrinsics.width;
  s.height = cameras.intrinsics.height;
  s.views = static_cast<int>(cameras.views.size());
  s.backend = renderer.backend();
  const std::size_t pixels = static_cast<std::size_t>(s.width) * s.height;
  s.pixels.assign(pixels * cameras.views.size(), 0.0f);
  for (int i = 0; i < s.views; ++i) {
    io::Stopwatch watch;
    const std::vector<float> floor = floors(cameras.intrinsics, cameras.views[i]);
    SplatSettings view_settings = settings;
    view_settings.floor = floor;
    renderer.forward(params, cameras.intrinsics, cameras.views[i], view_settings,
                     std::span<float>(s.pixels.data() + pixels * i, pixels));
    s.seconds_per_view.push_back(watch.elapsed());
    out.stats.push_back(renderer.stats());
    if (progress) progress(i + 1, s.views);
  }
  return out;
}

CameraSet turntable(const CameraOptions& options, int frames, double elevation_deg) {
  if (frames < 1 || frames > 100000) {
    throw io::InputError("orbit frames = " + std::to_string(frames) + ": must be in [1, 100000]");
  }
  CameraSet set;
  set.intrinsics = make_intrinsics(options);
  for (int j = 0; j < frames; ++j) {
    char name[32];
    std::snprintf(name, sizeof name, "orbit_%03d", j);
    set.views.push_back(orbit_view(elevation_deg, 360.0 * j / frames, options.orbit_radius, name));
  }
  return set;
}

}  // namespace hisnegs::splat
