// SPDX-License-Identifier: Apache-2.0
// `hisnegs eval --model m.ply --data GTDIR -o DIR`: options of the evaluation stage
// (pipeline/eval_stage.hpp) on GTDIR/eval, or GTDIR itself when it holds cameras.json.
#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/ground_truth_stage.hpp"
#include "apps/pipeline/eval_stage.hpp"
#include "io/config.hpp"

namespace hisnegs::apps {

void add_eval_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand(
      "eval", "measure a model on the evaluation views: PSNR, MAE, SSIM per view (metrics.json/csv)");
  struct Args {
    std::string model, data, out, mode, backend = "auto", volume;
    std::optional<double> beta;
    BackgroundOverride background;
    LodOverride lod;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("--model", args->model, "checkpoint (.ply or .hgs)")->required();
  cmd->add_option("--data", args->data, "ground-truth folder of `hisnegs gt` (uses GTDIR/eval)")->required();
  cmd->add_option("-o,--output", args->out, "output folder")->required();
  cmd->add_option("--mode", args->mode, "soft | hard (default splat.mode)");
  cmd->add_option("--beta", args->beta, "soft-MIP beta (default splat.beta)");
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  cmd->add_option("--volume", args->volume,
                  "the model's stack: also count its halos, the Gaussians brighter than the stack at their centre by "
                  "more than its noise");
  args->background.add_to(cmd);
  args->lod.add_to(cmd);
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    if (!args->mode.empty()) io::set_enum_field(config.splat, "mode", args->mode, "--mode");
    if (args->beta) config.splat.beta = *args->beta;
    args->background.apply(config.splat);
    config.splat.validate();
    const std::optional<splat::LodOptions> lod = args->lod.options();  // before the back end is looked for
    evaluate_model(args->model, ground_truth_set_dir(args->data, "eval"), args->out, EvalConfig(config),
                   splat::resolve_backend(splat::parse_backend_request(args->backend)), global.progress(),
                   args->volume, lod);
  });
}

}  // namespace hisnegs::apps
