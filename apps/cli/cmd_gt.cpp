// SPDX-License-Identifier: Apache-2.0
// `hisnegs gt VOLUME -o DIR`: options of the ground-truth stage
// (pipeline/ground_truth_stage.hpp): which orbits or cameras file, image size, mode.
#include "apps/cli/cli_support.hpp"
#include "io/memory_limit.hpp"
#include "apps/pipeline/ground_truth_stage.hpp"
#include "io/config.hpp"
#include "io/error.hpp"
#include "io/stack_file.hpp"

namespace hisnegs::apps {
namespace {

struct GtArgs {
  std::string volume, out, orbit = "both", cameras, mode, backend = "auto";
  std::optional<int> size;
  std::optional<double> radius, fov;
  std::vector<double> elevations, azimuths;
  std::optional<int> ring_views;
  StackReadingOverrides reading;
  VolumeOverrides overrides;
};

}  // namespace

void add_gt_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("gt", "ray-march ground-truth MIPs (cameras.json, mips.tif, previews, meta.json)");
  auto args = std::make_shared<GtArgs>();
  cmd->add_option("VOLUME", args->volume, kStackHelp)->required();
  cmd->add_option("-o,--output", args->out, "output folder")->required();
  cmd->add_option("--orbit", args->orbit, "train (106 views) | eval (30) | both (DIR/train, DIR/eval) | custom");
  cmd->add_option("--cameras", args->cameras, "render the views of this cameras.json instead of an orbit");
  cmd->add_option("--mode", args->mode, "exact | report (default from config: raymarch.mode)");
  cmd->add_option("--size", args->size, "image width = height in pixels (default from config)");
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  cmd->add_option("--elevations", args->elevations, "custom orbit: elevations in degrees, e.g. -30,0,30")
      ->check(finite_number() & CLI::Range(-90.0, 90.0))
      ->delimiter(',');
  cmd->add_option("--azimuths", args->azimuths, "custom orbit: azimuths in degrees, e.g. 0,90,180")
      ->delimiter(',')
      ->check(finite_number() & CLI::Range(-3600.0, 3600.0));
  cmd->add_option("--ring-views", args->ring_views, "custom orbit: N azimuths evenly spaced instead of --azimuths")
      ->check(CLI::Range(1, 3600));
  cmd->add_option("--radius", args->radius, "orbit radius (world units; default camera.orbit_radius)");
  cmd->add_option("--fov", args->fov, "horizontal field of view in degrees (default camera.fov_deg)");
  args->reading.add_to(cmd, "read and marched");
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
    std::vector<GroundTruthSet> sets;
    if (!args->cameras.empty()) {
      sets.push_back(GroundTruthSet{"cameras", splat::read_cameras_json(args->cameras)});
    } else if (args->orbit == "train") {
      sets.push_back(GroundTruthSet{"train", splat::training_orbit(config.camera)});
    } else if (args->orbit == "eval") {
      sets.push_back(GroundTruthSet{"eval", splat::evaluation_orbit(config.camera)});
    } else if (args->orbit == "both") {
      sets.push_back(GroundTruthSet{"train", splat::training_orbit(config.camera)});
      sets.push_back(GroundTruthSet{"eval", splat::evaluation_orbit(config.camera)});
    } else if (args->orbit == "custom") {
      if (args->elevations.empty()) throw io::InputError("--orbit custom: give --elevations");
      std::vector<double> azimuths = args->azimuths;
      if (args->ring_views) {
        if (*args->ring_views < 1) throw io::InputError("--ring-views must be >= 1");
        azimuths = splat::even_azimuths(*args->ring_views);
      }
      if (azimuths.empty()) throw io::InputError("--orbit custom: give --azimuths or --ring-views");
      sets.push_back(GroundTruthSet{"custom", splat::custom_orbit(config.camera, args->elevations, azimuths)});
    } else {
      throw io::InputError("--orbit = '" + args->orbit + "': expected train|eval|both|custom");
    }
    for (const GroundTruthSet& set : sets) {  // before anything else is said or done
      const splat::Intrinsics& K = set.cameras.intrinsics;
      const auto views = static_cast<double>(set.cameras.views.size());
      io::check_allocation("camera", 4.0 * K.width * K.height * views,
                           std::to_string(set.cameras.views.size()) + " float32 views of " + std::to_string(K.width) +
                               "x" + std::to_string(K.height));
    }
    config.volume.validate();
    const io::StackHeader header = io::inspect_stack(args->volume, io::stack_read_options(config.volume));
    const StackReading reading = args->reading.reading(config);
    const int core = ground_truth_core({header.nx, header.ny, header.nz}, reading, global.progress());
    // bricks are marched on the CPU; the whole stack on the back end asked for
    const splat::Backend backend =
        core > 0 ? splat::Backend::kCpu : splat::resolve_backend(splat::parse_backend_request(args->backend));
    write_ground_truth_sets(args->out, args->volume, sets, GroundTruthSetsConfig(config), backend, global.progress(),
                            core, reading);
  });
}

}  // namespace hisnegs::apps
