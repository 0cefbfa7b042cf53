// SPDX-License-Identifier: Apache-2.0
// render_views: one forward per view into the stack, timed per view; turntable().
#include "splat/render_views.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "io/error.hpp"
#include "io/timer.hpp"

namespace hisnegs::splat {

SoftPixel merge_soft_pixel(SoftPixel a, SoftPixel b) {
  if (!(a.S > 0)) return b;  // nothing reached a's pixel (m −∞, S 0)
  if (!(b.S > 0)) return a;
  const double m = std::max(a.m, b.m);
  const double wa = static_cast<double>(a.S) * std::exp(static_cast<double>(a.m) - m);
  const double wb = static_cast<double>(b.S) * std::exp(static_cast<double>(b.m) - m);
  const double S = wa + wb;
  return {static_cast<float>(m), static_cast<float>(S),
          static_cast<float>((wa * static_cast<double>(a.I) + wb * static_cast<double>(b.I)) / S)};
}

namespace {

// This process's render of its share made the whole model's (ShareCombiner).
void combine_view(SplatRenderer& renderer, const ShareCombiner& shares, const SplatSettings& settings,
                  std::span<const float> floor, std::span<float> image) {
  if (!settings.soft()) {
    shares.max(image);
    return;
  }
  std::vector<float> m(image.size()), S(image.size());
  renderer.soft_state(m, S);
  std::vector<SoftPixel> state(image.size());
  for (std::size_t i = 0; i < image.size(); ++i) state[i] = {m[i], S[i], image[i]};
  shares.merge_soft(state);
  for (std::size_t i = 0; i < image.size(); ++i) {
    image[i] = floor.empty() ? state[i].I : std::max(state[i].I, floor[i]);
  }
}

}  // namespace

RenderedViews render_views(SplatRenderer& renderer, std::span<const float> params, const CameraSet& cameras,
                           const SplatSettings& settings, const std::function<void(int, int)>& progress,
                           const BackgroundFloors& floors, const ShareCombiner* shares) {
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
    // A soft share is rendered without the floor: a max with it cannot be merged.
    if (!shares || !settings.soft()) view_settings.floor = floor;
    const std::span<float> image(s.pixels.data() + pixels * i, pixels);
    renderer.forward(params, cameras.intrinsics, cameras.views[i], view_settings, image);
    if (shares) combine_view(renderer, *shares, settings, floor, image);
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
