// SPDX-License-Identifier: Apache-2.0
// `hisnegs compare-optimizers VOLUME -o DIR`: options of the optimizer comparison
// (pipeline/optimizer_comparison.hpp; the comparison itself lives in gmf).
#include <sstream>
#include <vector>

#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/optimizer_comparison.hpp"
#include "io/config.hpp"
#include "io/error.hpp"

namespace hisnegs::apps {

namespace {

std::string registered_names() {
  std::string names;
  for (const gmf::NamedSolver& s : gmf::registered_optimizers()) names += (names.empty() ? "" : ", ") + s.name;
  return names;
}

}  // namespace

void add_compare_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("compare-optimizers",
                                 "fit with every optimizer from the same init and budget; table, CSV and plot in DIR");
  struct Args {
    std::string volume, out, optimizers, continuation = "brick-lm";
    std::optional<int> gaussians;
    gmf::CompareOptions compare;
    VolumeOverrides overrides;
  };
  auto args = std::make_shared<Args>();
  args->compare.time_budget_s = -1;  // default: gmf.time_budget_s
  cmd->add_option("VOLUME", args->volume, "stack: TIFF/BigTIFF, HDF5 (.h5), BigDataViewer (.xml), Imaris (.ims)")->required();
  cmd->add_option("-o,--output", args->out, "output folder")->required();
  cmd->add_option("--optimizers", args->optimizers,
                  "comma-separated subset of adam,brick-lm,lm-cgnr,lbfgs,lm,dogleg (default the first four) and of "
                  "the registered optimizers (gmf/optimizers.def: " + registered_names() + ")");
  cmd->add_option("--gaussians", args->gaussians, "Gaussian budget (gmf.gaussians)");
  cmd->add_option("--time-budget", args->compare.time_budget_s, "seconds per optimizer (default gmf.time_budget_s)");
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
    if (compare.time_budget_s < 0) compare.time_budget_s = config.gmf.time_budget_s;
    const auto optimizers = [](const std::string& text, const char* option) {
      std::vector<gmf::Optimizer> out;
      std::stringstream list(text);
      for (std::string name; std::getline(list, name, ',');) {
        gmf::GmfOptions parsed;
        io::set_enum_field(parsed, "optimizer", name, option);
        out.push_back(parsed.optimizer);
      }
      return out;
    };
    if (!args->optimizers.empty()) {
      // Built-in names go to compare.optimizers, registered ones (gmf/optimizers.def) to compare.custom.
      std::string builtin;
      std::stringstream list(args->optimizers);
      for (std::string name; std::getline(list, name, ',');) {
        if (const gmf::NamedSolver* registered = gmf::find_registered_optimizer(name)) {
          compare.custom.push_back(*registered);
        } else {
          builtin += (builtin.empty() ? "" : ",") + name;
        }
      }
      try {
        compare.optimizers = builtin.empty() ? std::vector<gmf::Optimizer>{} : optimizers(builtin, "--optimizers");
      } catch (const io::InputError& e) {
        throw io::InputError(std::string(e.what()) + ", or a registered one: " + registered_names());
      }
    }
    compare.continuation =
        args->continuation == "none" ? std::vector<gmf::Optimizer>{} : optimizers(args->continuation, "--continuation");
    compare.validate();
    write_optimizer_comparison(args->out, args->volume, FitConfig(config), compare, global.progress());
  });
}

}  // namespace hisnegs::apps
