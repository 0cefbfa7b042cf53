// `hisnegs render --model m.ply --cameras cams.json -o DIR`: soft/hard-MIP splats of
// a checkpoint: DIR/render.tif (float32, one page per view, cameras-file order),
// DIR/previews/NNN.png, DIR/render.json; `--orbit N` adds DIR/orbit.gif.
#include <algorithm>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/ground_truth_stage.hpp"
#include "apps/pipeline/orbit_stage.hpp"
#include "gmf/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/gif.hpp"
#include "io/png.hpp"
#include "io/tiff_stack.hpp"
#include "io/timer.hpp"
#include "splat/render_views.hpp"

namespace hisnegs::apps {
namespace {

struct RenderArgs {
  std::string model, cameras, out, mode, backend = "auto";
  std::optional<double> beta;
  std::optional<int> orbit, size;
  double elevation = 20.0;
  int delay_ms = 50;
};

double median_ms(std::vector<double> seconds) {
  if (seconds.empty()) return 0;
  std::sort(seconds.begin(), seconds.end());
  return 1e3 * seconds[seconds.size() / 2];
}

}  // namespace

void add_render_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("render", "render a checkpoint as soft/hard MIP splats (render.tif, previews, orbit GIF)");
  auto args = std::make_shared<RenderArgs>();
  cmd->add_option("--model", args->model, "checkpoint (.ply)")->required();
  cmd->add_option("--cameras", args->cameras, "cameras.json whose views to render (e.g. GTDIR/eval/cameras.json)");
  cmd->add_option("-o,--output", args->out, "output folder")->required();
  cmd->add_option("--mode", args->mode, "soft | hard (default splat.mode)");
  cmd->add_option("--beta", args->beta, "soft-MIP beta (default splat.beta)");
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  cmd->add_option("--orbit", args->orbit, "also write orbit.gif: N frames of a 360 degree orbit");
  cmd->add_option("--elevation", args->elevation, "orbit elevation in degrees")->capture_default_str();
  cmd->add_option("--size", args->size, "orbit image width = height (default camera.width/height)");
  cmd->add_option("--frame-ms", args->delay_ms, "orbit GIF frame time in ms")->capture_default_str();
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    if (!args->mode.empty()) io::set_enum_field(config.splat, "mode", args->mode, "--mode");
    if (args->beta) config.splat.beta = *args->beta;
    if (args->size) config.camera.width = config.camera.height = *args->size;
    config.splat.validate();
    config.camera.validate();
    if (args->cameras.empty() && !args->orbit) throw io::InputError("render: give --cameras FILE and/or --orbit N");
    const splat::Backend backend = splat::resolve_backend(splat::parse_backend_request(args->backend));
    const gmf::Checkpoint checkpoint = gmf::load_checkpoint(args->model);
    const auto params = splat::flat_params(checkpoint.mixture);
    const splat::SplatSettings settings = splat::SplatSettings::from(config.splat);
    auto renderer = splat::make_splat_renderer(backend);
    const std::filesystem::path dir = args->out;
    const char* mode = settings.mode == splat::MipMode::kSoft ? "soft" : "hard";
    nlohmann::ordered_json meta;
    meta["model"] = io::printable(args->model, 500);
    meta["gaussians"] = checkpoint.mixture.size();
    meta["mode"] = mode;
    meta["beta"] = settings.beta;
    meta["backend"] = std::string(splat::to_string(backend));

    if (!args->cameras.empty()) {
      const splat::CameraSet cameras = splat::read_cameras_json(args->cameras);
      const splat::RenderedViews r = splat::render_views(*renderer, params, cameras, settings);
      const splat::MipStack& s = r.stack;
      write_image_stack(dir, "render.tif", s);
      meta["cameras"] = io::printable(args->cameras, 500);
      meta["views"] = s.views;
      meta["width"] = s.width;
      meta["height"] = s.height;
      meta["median_ms_per_view"] = median_ms(s.seconds_per_view);
      if (!global.quiet) {
        std::printf("render: %d views of %dx%d, K %zu (%d visible in view 0), %s MIP, %s, median %.2f ms/view -> %s\n",
                    s.views, s.width, s.height, checkpoint.mixture.size(), r.stats.empty() ? 0 : r.stats[0].visible,
                    mode, std::string(splat::to_string(backend)).c_str(), median_ms(s.seconds_per_view),
                    (dir / "render.tif").c_str());
      }
    }
    if (args->orbit) {
      const std::vector<double> seconds = write_orbit_gif(dir / "orbit.gif", *renderer, params, OrbitConfig(config),
                                                          {*args->orbit, args->elevation, args->delay_ms});
      meta["orbit"] = {{"frames", *args->orbit},
                       {"elevation_deg", args->elevation},
                       {"median_ms_per_frame", median_ms(seconds)}};
      if (!global.quiet) {
        std::printf("render: orbit of %d frames at %.3g deg elevation, median %.2f ms/frame -> %s\n", *args->orbit,
                    args->elevation, median_ms(seconds), (dir / "orbit.gif").c_str());
      }
    }
    const std::string text = meta.dump(2) + "\n";
    io::write_file_atomic(dir / "render.json", text.data(), text.size());
  });
}

}  // namespace hisnegs::apps
