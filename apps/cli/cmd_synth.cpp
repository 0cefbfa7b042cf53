// SPDX-License-Identifier: Apache-2.0
// `hisnegs synth -o vol.tif`: options of the synthetic neuron stack (config section
// `synth`, pipeline/synthetic_stack.hpp).
#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/synthetic_stack.hpp"
#include "io/error.hpp"

namespace hisnegs::apps {

void add_synth_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("synth", "write a realistic synthetic neuron stack (uint16 TIFF)");
  struct Args {
    std::string out;
    std::optional<std::uint64_t> seed;
    std::vector<int> shape_zyx;
    std::string noise;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("-o,--output", args->out, "output TIFF path")->required();
  cmd->add_option("--seed", args->seed, "random seed (default from config: synth.seed)");
  cmd->add_option("--shape", args->shape_zyx, "stack shape Z,Y,X (default from config)")->delimiter(',');
  cmd->add_option("--noise", args->noise,
                  "subtracted (the camera offset and read noise subtracted, background mostly 0, like the shared "
                  "stacks) | raw (as the detector gives it: offset, read noise and background photons kept) "
                  "(default from config: synth.background_subtract)");
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    simulate::SyntheticNeuronOptions& options = config.synth;
    if (args->seed) options.seed = *args->seed;
    if (!args->shape_zyx.empty()) {
      if (args->shape_zyx.size() != 3) {
        throw io::InputError("--shape: expected 3 values Z,Y,X, got " + std::to_string(args->shape_zyx.size()));
      }
      options.nz = args->shape_zyx[0];
      options.ny = args->shape_zyx[1];
      options.nx = args->shape_zyx[2];
    }
    if (!args->noise.empty()) {
      if (args->noise != "subtracted" && args->noise != "raw") {
        throw io::InputError("--noise = '" + io::printable(args->noise, 40) + "': expected subtracted or raw");
      }
      options.background_subtract = args->noise == "subtracted";
    }
    options.validate();
    write_synthetic_stack(args->out, SyntheticConfig(config), global.progress());
  });
}

}  // namespace hisnegs::apps
