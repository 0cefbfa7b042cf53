// SPDX-License-Identifier: Apache-2.0
// `hisnegs compare-optimizers VOLUME -o DIR`: options of the optimizer comparison
// (pipeline/optimizer_comparison.hpp; the comparison itself lives in gmf).
#include <sstream>
#include <vector>

#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/optimizer_comparison.hpp"

namespace hisnegs::apps {

void add_compare_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("compare-optimizers",
                                 "fit with every optimizer from the same init and budget; table, CSV and plot in DIR");
  struct Args {
    std::string volume, out, optimizers, continuation = "brick-lm";
    std::optional<int> gaussians;
    std::optional<double> time_budget;
    gmf::CompareOptions compare;
    VolumeOverrides overrides;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("VOLUME", args->volume, kStackHelp)->required();
  cmd->add_option("-o,--output", args->out, "output folder")->required();
  cmd->add_option("--optimizers", args->optimizers,
                  "comma-separated subset of adam,brick-lm,lm-cgnr,lbfgs,lm,dogleg (default the first four) and of "
                  "the registered optimizers (gmf/optimizers.def: " + gmf::registered_optimizer_names() + ")");
  cmd->add_option("--gaussians", args->gaussians, "Gaussian budget (gmf.gaussians)");
  cmd->add_option("--time-budget", args->time_budget, "seconds per optimizer, > 0 (default gmf.time_budget_s)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--adam-steps", args->compare.adam_steps, "Adam steps that define the target loss")
      ->capture_default_str();
  cmd->add_option("--continuation", args->continuation,
                  "optimizers that follow the β schedule towards gmf.beta_end (adam, brick-lm, or none); the others "
                  "solve at beta_end from the start; every loss is logged at beta_end")
      ->capture_default_str();
  cmd->add_flag("--stop-at-target", args->compare.stop_at_target, "end each run once it reaches the target loss");
  args->overrides.add_to(cmd);
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    args->overrides.apply(config.volume);
    if (args->gaussians) config.gmf.gaussians = *args->gaussians;
    config.gmf.validate();
    gmf::CompareOptions compare = args->compare;
    compare.time_budget_s = args->time_budget.value_or(config.gmf.time_budget_s);
    const auto names = [](const std::string& text) {
      std::vector<std::string> out;
      std::stringstream list(text);
      for (std::string name; std::getline(list, name, ',');) out.push_back(name);
      return out;
    };
    if (!args->optimizers.empty()) {
      compare.optimizers.clear();
      gmf::add_optimizers(compare, names(args->optimizers), "--optimizers");
    }
    compare.continuation.clear();
    if (args->continuation != "none") {
      compare.continuation = gmf::builtin_optimizers(names(args->continuation), "--continuation");
    }
    compare.validate();
    write_optimizer_comparison(args->out, args->volume, FitConfig(config), compare, global.progress());
  });
}

}  // namespace hisnegs::apps
