// SPDX-License-Identifier: Apache-2.0
// `hisnegs render --model m.ply --cameras cams.json -o DIR`: options of rendering a
// checkpoint (pipeline/render_model.hpp); `--orbit N` adds DIR/orbit.gif.
#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/render_model.hpp"
#include "io/config.hpp"

namespace hisnegs::apps {

void add_render_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd =
      app.add_subcommand("render", "render a checkpoint as soft/hard MIP splats (render.tif, previews, orbit GIF)");
  struct Args {
    std::string model, cameras, out, mode, backend = "auto";
    std::optional<double> beta;
    BackgroundOverride background;
    std::optional<int> orbit, size;
    LodOverride lod;
    double elevation = 20.0;
    int delay_ms = 50;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("--model", args->model, "checkpoint (.ply or .hgs)")->required();
  cmd->add_option("--cameras", args->cameras, "cameras.json whose views to render (e.g. GTDIR/eval/cameras.json)");
  cmd->add_option("-o,--output", args->out, "output folder")->required();
  cmd->add_option("--mode", args->mode, "soft | hard (default splat.mode)");
  cmd->add_option("--beta", args->beta, "soft-MIP beta (default splat.beta)");
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  args->background.add_to(cmd);
  cmd->add_option("--orbit", args->orbit, "also write orbit.gif: N frames of a 360 degree orbit");
  cmd->add_option("--elevation", args->elevation, "orbit elevation in degrees")->capture_default_str();
  cmd->add_option("--size", args->size, "orbit image width = height (default camera.width/height)");
  cmd->add_option("--frame-ms", args->delay_ms, "orbit GIF frame time in ms")->capture_default_str();
  args->lod.add_to(cmd);
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    if (!args->mode.empty()) io::set_enum_field(config.splat, "mode", args->mode, "--mode");
    if (args->beta) config.splat.beta = *args->beta;
    args->background.apply(config.splat);
    if (args->size) config.camera.width = config.camera.height = *args->size;
    config.splat.validate();
    config.camera.validate();
    if (args->cameras.empty() && !args->orbit) throw io::InputError("render: give --cameras FILE and/or --orbit N");
    RenderRequest request;
    request.model = args->model;
    request.cameras = args->cameras;
    request.dir = args->out;
    request.lod = args->lod.options();  // options checked before the back end is looked for
    if (request.lod && args->cameras.empty()) {
      throw io::InputError("render: --lod draws the views of --cameras (not the orbit)");
    }
    request.backend = splat::resolve_backend(splat::parse_backend_request(args->backend));
    if (args->orbit) request.orbit = OrbitOptions{*args->orbit, args->elevation, args->delay_ms};
    render_model(request, RenderConfig(config), global.progress());
  });
}

}  // namespace hisnegs::apps
