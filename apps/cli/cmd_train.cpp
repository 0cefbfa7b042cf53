// SPDX-License-Identifier: Apache-2.0
// `hisnegs train --init gmf.ply --data GTDIR [--volume V.tif] -o RUNDIR`: options of the training
// stage (pipeline/train_stage.hpp) on GTDIR/train; --resume continues.
#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/ground_truth_stage.hpp"
#include "apps/pipeline/train_stage.hpp"

namespace hisnegs::apps {

void add_train_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("train", "train Gaussians on ground-truth MIPs by soft-MIP splatting (report §6)");
  struct Args {
    std::string init, data, out, volume, backend = "auto";
    bool resume = false;
    std::optional<int> epochs;
    StackReadingOverrides reading;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("--init", args->init, "initial model (.ply or .hgs, e.g. from `hisnegs fit`)")->required();
  cmd->add_option("--data", args->data, "ground-truth folder of `hisnegs gt`: GTDIR/train (gt --orbit both), or GTDIR itself when it holds one set (cameras.json + mips.tif)")->required();
  cmd->add_option("-o,--output", args->out, "run folder (log.csv, checkpoints/, final.ply, training_curve.png)")
      ->required();
  cmd->add_option("--volume", args->volume,
                  "the stack the model was fitted to: adds the 3D term (train.lambda_3d) and prunes Gaussians "
                  "in empty space (default: the views only)");
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  cmd->add_flag("--resume", args->resume, "continue from RUNDIR/checkpoints/latest");
  cmd->add_option("--epochs", args->epochs, "number of epochs (train.epochs)");
  args->reading.add_to(cmd, "(--volume) read");
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    if (args->epochs) config.train.epochs = *args->epochs;
    const splat::Backend backend = splat::resolve_backend(splat::parse_backend_request(args->backend));
    choose_train_schedule(config, backend, global.progress());
    train_model({args->init, ground_truth_set_dir(args->data, "train"), args->out, backend, args->resume,
                 args->volume, args->reading.reading(config)},
                TrainConfig(config), global.progress());
  });
}

}  // namespace hisnegs::apps
