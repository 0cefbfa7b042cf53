// SPDX-License-Identifier: Apache-2.0
// `hisnegs run VOLUME -o DIR`: options of the whole pipeline in one folder
// (pipeline/run_pipeline.hpp): reused stages are skipped; --force redoes everything.
#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/run_pipeline.hpp"
#include "apps/pipeline/train_stage.hpp"
#include "io/error.hpp"
#include "io/stack_file.hpp"

namespace hisnegs::apps {

void add_run_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand(
      "run", "the whole pipeline: ground truth, GMF fit, training, evaluation, orbit GIF and report.md in one folder");
  struct Args {
    std::string volume, out, backend = "auto";
    bool force = false;
    int orbit_frames = 72;
    double orbit_elevation = 30.0;
    VolumeOverrides overrides;
    StackReadingOverrides reading;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("VOLUME", args->volume, kStackHelp)->required();
  cmd->add_option("-o,--output", args->out, "run folder (reused stages are skipped)")->required();
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  cmd->add_flag("--force", args->force, "redo every stage, even those finished earlier");
  cmd->add_option("--orbit-frames", args->orbit_frames, "frames of the 360 degree orbit GIF")->capture_default_str();
  cmd->add_option("--orbit-elevation", args->orbit_elevation, "orbit elevation in degrees")->capture_default_str();
  args->overrides.add_to(cmd);
  args->reading.add_to(cmd, "read (volume, gt, training) and fitted (gmf.max_memory, gmf.stream_brick_voxels)");
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    args->overrides.apply(config.volume);
    if (args->reading.max_memory) config.gmf.max_memory = *args->reading.max_memory;
    if (args->reading.brick_voxels) config.gmf.stream_brick_voxels = *args->reading.brick_voxels;
    io::require_stack_path(args->volume);  // before the back-end notice: a bad path is the one line
    const splat::Backend backend = splat::resolve_backend(splat::parse_backend_request(args->backend));
    choose_train_schedule(config, backend, global.progress());
    run_pipeline({args->volume, args->out, backend, args->force, args->orbit_frames, args->orbit_elevation,
                  args->reading.reading(config)},
                 config, global.progress());
  });
}

}  // namespace hisnegs::apps
