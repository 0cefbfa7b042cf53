// SPDX-License-Identifier: Apache-2.0
// write_orbit_gif and the run folder's orbit stage.
#include "apps/pipeline/orbit_stage.hpp"

#include <nlohmann/json.hpp>

#include "apps/pipeline/format.hpp"
#include "gmf/core/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "io/gif.hpp"
#include "io/png.hpp"
#include "splat/render_views.hpp"

namespace hisnegs::apps {

std::vector<double> write_orbit_gif(const std::filesystem::path& gif, splat::SplatRenderer& renderer,
                                    std::span<const float> params, const OrbitConfig& config,
                                    const OrbitOptions& orbit, const splat::BackgroundFloors& floors,
                                    const splat::ShareCombiner* shares) {
  const splat::CameraSet cameras =
      splat::turntable(config.get<&AppConfig::camera>(), orbit.frames, orbit.elevation_deg);
  const splat::RenderedViews r = splat::render_views(
      renderer, params, cameras, splat::SplatSettings::from(config.get<&AppConfig::splat>()), {}, floors, shares);
  if (gif.empty()) return r.stack.seconds_per_view;
  std::vector<io::Image8> images;
  images.reserve(static_cast<std::size_t>(r.stack.views));
  for (int i = 0; i < r.stack.views; ++i)
    images.push_back(io::to_gray8(r.stack.view(i), r.stack.width, r.stack.height));
  io::write_gif(gif, images, orbit.delay_ms);
  return r.stack.seconds_per_view;
}

std::string OrbitStage::request_inputs(const RunRequest& request) {
  return strf("frames %d elevation %.17g\n", request.orbit_frames, request.orbit_elevation);
}

nlohmann::ordered_json OrbitStage::run(const RunRequest& request, const Config& config, bool,
                                       const Progress& progress) {
  const std::filesystem::path& dir = request.dir;
  const gmf::Checkpoint model = gmf::load_checkpoint((dir / "train" / "final.ply").string());
  auto renderer = splat::make_splat_renderer(request.backend);
  const splat::BackgroundFloors floors = splat::floors_of(model.meta, (dir / "train" / "final.ply").string(),
                                                         config.get<&AppConfig::splat>().background);
  const std::vector<double> seconds =
      write_orbit_gif(dir / "orbit.gif", *renderer, splat::flat_params(model.mixture), config,
                      {request.orbit_frames, request.orbit_elevation, 50}, floors);
  const splat::CameraOptions& camera = config.get<&AppConfig::camera>();
  const nlohmann::ordered_json info{{"frames", request.orbit_frames},
                                    {"elevation_deg", request.orbit_elevation},
                                    {"width", camera.width},
                                    {"height", camera.height},
                                    {"gaussians", model.mixture.size()},
                                    {"backend", std::string(splat::to_string(request.backend))},
                                    {"seconds_per_frame", seconds}};
  const std::string text = info.dump(2) + "\n";
  io::write_file_atomic(dir / "orbit.json", text.data(), text.size());
  progress.say("run: orbit: %d frames -> %s", request.orbit_frames, (dir / "orbit.gif").c_str());
  return nullptr;
}

}  // namespace hisnegs::apps
