// `hisnegs gt VOLUME -o DIR`: ground-truth MIPs of the training/evaluation orbits
// (or a cameras file / custom orbit): cameras.json, mips.tif, previews/, meta.json.
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "apps/cli/cli_support.hpp"
#include "apps/cli/commands_detail.hpp"
#include "apps/pipeline/report_tables.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/load_volume.hpp"
#include "io/png.hpp"
#include "io/tiff_stack.hpp"
#include "io/timer.hpp"
#include "splat/ground_truth.hpp"
#include "splat/raymarch.hpp"

namespace hisnegs::apps {
namespace {

struct GtArgs {
  std::string volume, out, orbit = "both", cameras, mode, backend = "auto";
  std::optional<int> size;
  std::optional<double> radius, fov;
  std::vector<double> elevations, azimuths;
  std::optional<int> ring_views;
  VolumeOverrides overrides;
};

}  // namespace

void write_image_stack(const std::filesystem::path& dir, const std::string& name, const splat::MipStack& stack) {
  io::TiffWriteOptions tiff;
  tiff.type = io::SampleType::kFloat32;
  io::write_tiff_stack(dir / name, stack.pixels, stack.width, stack.height, stack.views, tiff);
  for (int i = 0; i < stack.views; ++i) {
    char file[32];
    std::snprintf(file, sizeof file, "%03d.png", i);
    io::write_png(dir / "previews" / file, io::to_gray8(stack.view(i), stack.width, stack.height));
  }
}

void write_ground_truth_set(const std::filesystem::path& dir, const std::string& label,
                            const splat::CameraSet& cameras, const io::LoadedVolume& loaded,
                            const std::string& volume_path, const splat::RaymarchOptions& rm, splat::Backend backend,
                            bool quiet) {
  const bool tty = ::isatty(STDERR_FILENO);
  io::Stopwatch watch;
  const splat::MipStack stack = splat::render_ground_truth(
      loaded.volume, loaded.frame, cameras, rm, backend, [&](int done, int total) {
        if (quiet) return;
        const double per_view = watch.elapsed() / done;
        if (tty || done == total) {
          std::fprintf(stderr, "%sgt %s: %d/%d views, %.1f ms/view, ETA %s%s", tty ? "\r" : "", label.c_str(), done,
                       total, per_view * 1e3, format_seconds(per_view * (total - done)).c_str(), done == total ? "\n" : "");
        }
      });
  const double render_s = watch.lap();
  splat::write_cameras_json(dir / "cameras.json", cameras);
  write_image_stack(dir, "mips.tif", stack);
  nlohmann::ordered_json meta;
  const io::Volume& v = loaded.volume;
  meta["volume"] = volume_path;
  meta["volume_shape_zyx"] = {v.nz, v.ny, v.nx};
  meta["spacing_um"] = {v.spacing.um[0], v.spacing.um[1], v.spacing.um[2]};
  meta["spacing_source"] = v.spacing.describe();
  meta["normalization"] = {{"method", std::string(io::to_string(v.normalization.method))},
                           {"raw_lo", v.normalization.raw_lo},
                           {"raw_hi", v.normalization.raw_hi}};
  const Eigen::Vector3d& a = loaded.frame.aspect();
  meta["aspect"] = {a.x(), a.y(), a.z()};
  meta["mode"] = rm.mode == splat::RaymarchMode::kExact ? "exact" : "report";
  if (rm.mode == splat::RaymarchMode::kExact) {
    meta["step_world"] = splat::exact_step(loaded.frame, rm);
  } else {
    meta["samples"] = rm.samples;
    meta["t_near"] = rm.t_near;
    meta["t_far"] = rm.t_far;
  }
  meta["views"] = stack.views;
  meta["width"] = stack.width;
  meta["height"] = stack.height;
  meta["backend"] = std::string(splat::to_string(stack.backend));
  meta["timing"] = {{"render_s", render_s},
                    {"median_ms_per_view", 1e3 * median(stack.seconds_per_view)},
                    {"mean_ms_per_view", 1e3 * render_s / std::max(stack.views, 1)}};
  const std::string text = meta.dump(2) + "\n";
  io::write_file_atomic(dir / "meta.json", text.data(), text.size());
  if (!quiet) {
    std::printf("gt: %s: %d views of %dx%d (%s mode, %s) in %s, median %.1f ms/view -> %s\n", label.c_str(),
                stack.views, stack.width, stack.height, meta["mode"].get<std::string>().c_str(),
                std::string(splat::to_string(stack.backend)).c_str(), format_seconds(render_s).c_str(),
                1e3 * median(stack.seconds_per_view), dir.c_str());
  }
}

void add_gt_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("gt", "ray-march ground-truth MIPs (cameras.json, mips.tif, previews, meta.json)");
  auto args = std::make_shared<GtArgs>();
  cmd->add_option("VOLUME", args->volume, "TIFF stack")->required();
  cmd->add_option("-o,--output", args->out, "output folder")->required();
  cmd->add_option("--orbit", args->orbit, "train (106 views) | eval (30) | both (DIR/train, DIR/eval) | custom");
  cmd->add_option("--cameras", args->cameras, "render the views of this cameras.json instead of an orbit");
  cmd->add_option("--mode", args->mode, "exact | report (default from config: raymarch.mode)");
  cmd->add_option("--size", args->size, "image width = height in pixels (default from config)");
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  cmd->add_option("--elevations", args->elevations, "custom orbit: elevations in degrees, e.g. -30,0,30")->delimiter(',');
  cmd->add_option("--azimuths", args->azimuths, "custom orbit: azimuths in degrees, e.g. 0,90,180")->delimiter(',');
  cmd->add_option("--ring-views", args->ring_views, "custom orbit: N azimuths evenly spaced instead of --azimuths");
  cmd->add_option("--radius", args->radius, "orbit radius (world units; default camera.orbit_radius)");
  cmd->add_option("--fov", args->fov, "horizontal field of view in degrees (default camera.fov_deg)");
  args->overrides.add_to(cmd);
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    args->overrides.apply(config.volume);
    if (args->size) config.camera.width = config.camera.height = *args->size;
    if (args->radius) config.camera.orbit_radius = *args->radius;
    if (args->fov) config.camera.fov_deg = *args->fov;
    if (!args->mode.empty()) io::set_enum_field(config.raymarch, "mode", args->mode, "--mode");
    config.camera.validate();
    config.raymarch.validate();
    const bool custom = !args->elevations.empty() || !args->azimuths.empty() || args->ring_views;
    if (custom && args->orbit == "both") args->orbit = "custom";
    std::vector<std::pair<std::string, splat::CameraSet>> sets;
    if (!args->cameras.empty()) {
      sets.emplace_back("cameras", splat::read_cameras_json(args->cameras));
    } else if (args->orbit == "train") {
      sets.emplace_back("train", splat::training_orbit(config.camera));
    } else if (args->orbit == "eval") {
      sets.emplace_back("eval", splat::evaluation_orbit(config.camera));
    } else if (args->orbit == "both") {
      sets.emplace_back("train", splat::training_orbit(config.camera));
      sets.emplace_back("eval", splat::evaluation_orbit(config.camera));
    } else if (args->orbit == "custom") {
      if (args->elevations.empty()) throw io::InputError("--orbit custom: give --elevations");
      std::vector<double> azimuths = args->azimuths;
      if (args->ring_views) {
        if (*args->ring_views < 1) throw io::InputError("--ring-views must be >= 1");
        azimuths = splat::even_azimuths(*args->ring_views);
      }
      if (azimuths.empty()) throw io::InputError("--orbit custom: give --azimuths or --ring-views");
      sets.emplace_back("custom", splat::custom_orbit(config.camera, args->elevations, azimuths));
    } else {
      throw io::InputError("--orbit = '" + args->orbit + "': expected train|eval|both|custom");
    }
    const splat::Backend backend = splat::resolve_backend(splat::parse_backend_request(args->backend));
    io::Stopwatch watch;
    const io::LoadedVolume loaded = io::load_volume(args->volume, config.volume);
    if (!global.quiet) {
      std::printf("gt: loaded %s (X=%d Y=%d Z=%d, aspect %.4g %.4g %.4g) in %s\n", args->volume.c_str(),
                  loaded.volume.nx, loaded.volume.ny, loaded.volume.nz, loaded.frame.aspect().x(),
                  loaded.frame.aspect().y(), loaded.frame.aspect().z(), format_seconds(watch.lap()).c_str());
    }
    const std::filesystem::path out = args->out;
    for (const auto& [label, cameras] : sets) {
      const auto dir = sets.size() > 1 ? out / label : out;
      write_ground_truth_set(dir, label, cameras, loaded, args->volume, config.raymarch, backend, global.quiet);
    }
  });
}

}  // namespace hisnegs::apps
