// SPDX-License-Identifier: Apache-2.0
// `hisnegs fit VOLUME -o model.ply`: options of the GMF stage (pipeline/fit_stage.hpp).
#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/fit_stage.hpp"
#include "io/config.hpp"

namespace hisnegs::apps {

void add_fit_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd =
      app.add_subcommand("fit", "fit a Gaussian Mixture Field to a stack with Ceres (writes a .ply checkpoint)");
  struct Args {
    std::string volume, out, optimizer, aggregation, log, init;
    std::optional<int> gaussians;
    std::optional<double> time_budget;
    std::optional<std::string> max_memory;
    std::optional<int> brick_voxels;
    VolumeOverrides overrides;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("VOLUME", args->volume, kStackHelp)->required();
  cmd->add_option("-o,--output", args->out, "output checkpoint (.ply)")->required();
  cmd->add_option("--optimizer", args->optimizer, "adam | brick-lm | lm | lm-cgnr | dogleg | lbfgs (gmf.optimizer)");
  cmd->add_option("--aggregation", args->aggregation,
                  "softmax (f -> max, what MIPs show) | sum (report Eq. 1, density export) (gmf.aggregation)");
  cmd->add_option("--gaussians", args->gaussians, "Gaussian budget (gmf.gaussians)");
  cmd->add_option("--time-budget", args->time_budget, "wall-clock limit in seconds (gmf.time_budget_s; 0: none, the schedule alone)");
  cmd->add_option("--max-memory", args->max_memory,
                  "most memory the fit may use (gmf.max_memory: auto = half the RAM, or 1GiB, 512MiB); a stack that "
                  "does not fit is fitted in bricks");
  cmd->add_option("--brick-voxels", args->brick_voxels,
                  "fit in bricks of this core edge (voxels) even when the stack fits (gmf.stream_brick_voxels)");
  cmd->add_option("--init", args->init,
                  "start from this model of the same stack (a coarser --level's fit, or an earlier fit) instead of "
                  "gmf.init: its Gaussians inside the stack, the brightest gmf.gaussians, beta from gmf.beta_end");
  cmd->add_option("--log", args->log, "CSV of iteration, seconds, loss, foreground and 3D PSNR, K, round, beta");
  args->overrides.add_to(cmd);
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    args->overrides.apply(config.volume);
    if (!args->optimizer.empty()) io::set_enum_field(config.gmf, "optimizer", args->optimizer, "--optimizer");
    if (!args->aggregation.empty()) {
      io::set_enum_field(config.gmf, "aggregation", args->aggregation, "--aggregation");
    }
    if (args->gaussians) config.gmf.gaussians = *args->gaussians;
    if (args->time_budget) config.gmf.time_budget_s = *args->time_budget;
    if (args->max_memory) config.gmf.max_memory = *args->max_memory;
    if (args->brick_voxels) config.gmf.stream_brick_voxels = *args->brick_voxels;
    config.gmf.validate();
    fit_to_checkpoint(args->volume, FitConfig(config), args->out, args->log, global.progress(), args->init);
  });
}

}  // namespace hisnegs::apps
