// SPDX-License-Identifier: Apache-2.0
// Rendering a checkpoint (config sections camera, splat): the views of a cameras
// file as a stack with previews, and/or a turntable GIF, described in render.json.
#pragma once

#include <filesystem>
#include <optional>

#include "apps/pipeline/orbit_stage.hpp"
#include "apps/pipeline/progress.hpp"
#include "splat/backend.hpp"
#include "splat/lod.hpp"

namespace hisnegs::apps {

using RenderConfig = OrbitConfig;

struct RenderRequest {
  std::filesystem::path model;        // checkpoint (.ply)
  std::filesystem::path cameras;      // cameras.json whose views to render; empty: none
  std::filesystem::path dir;          // output folder
  std::optional<OrbitOptions> orbit;  // also DIR/orbit.gif
  splat::Backend backend = splat::Backend::kCpu;
  // The cameras' views drawn from the model's hierarchy (gmf/core/hierarchy.hpp) as
  // the viewer selects it; render.json records each view's Gaussian count.
  std::optional<splat::LodOptions> lod;
};

// Writes DIR/render.tif (float32, one page per view, cameras-file order) with
// DIR/previews/NNN.png, and/or DIR/orbit.gif; DIR/render.json in both cases; a line
// for each. Throws io::InputError when neither cameras nor an orbit is asked for.
void render_model(const RenderRequest& request, const RenderConfig& config, const Progress& progress);

}  // namespace hisnegs::apps
