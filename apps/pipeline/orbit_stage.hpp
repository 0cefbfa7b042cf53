// SPDX-License-Identifier: Apache-2.0
// The orbit stage (config sections camera, splat): a 360 degree turntable of a
// model rendered as an animated GIF, with the render time of every frame.
#pragma once

#include <filesystem>
#include <span>
#include <vector>

#include "apps/pipeline/config_slice.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/run_stage.hpp"
#include "splat/background_floor.hpp"
#include "splat/render_views.hpp"
#include "splat/splat_renderer.hpp"

namespace hisnegs::apps {

using OrbitConfig = ConfigSlice<&AppConfig::camera, &AppConfig::splat>;

struct OrbitOptions {
  int frames = 72;            // views of the turntable, [1, 3600]; report Table 10: 72 (5 degree steps)
  double elevation_deg = 30;  // camera elevation in degrees
  int delay_ms = 50;          // GIF frame time
};

// Renders the orbit of `params` (camera intrinsics and radius from `camera`, splatting
// settings from `splat`) over the model's background `floors` and writes it to `gif`;
// returns each frame's render time (s). With `shares` (render_views), `params` is this
// process's share of the model; an empty `gif` renders without writing (the MPI
// ranks that do not keep the images).
std::vector<double> write_orbit_gif(const std::filesystem::path& gif, splat::SplatRenderer& renderer,
                                    std::span<const float> params, const OrbitConfig& config,
                                    const OrbitOptions& orbit, const splat::BackgroundFloors& floors = {},
                                    const splat::ShareCombiner* shares = nullptr);

// In a run folder: DIR/orbit.gif of DIR/train/final.ply and DIR/orbit.json (frames,
// elevation, size, K, back end, seconds per frame).
struct OrbitStage {
  using Config = OrbitConfig;
  static constexpr const char* kName = "orbit";
  static constexpr const char* kTitle = "orbit GIF";
  static constexpr std::array<const char*, 1> kUpstream{"train"};
  static constexpr std::array<const char*, 2> kOutputs{"orbit.gif", "orbit.json"};
  static constexpr const char* kResumeMarker = "";
  static std::string request_inputs(const RunRequest& request);  // frames and elevation
  static nlohmann::ordered_json run(const RunRequest& request, const Config& config, bool resume,
                                    const Progress& progress);
};

}  // namespace hisnegs::apps
