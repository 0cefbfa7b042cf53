// `hisnegs synth -o vol.tif`: the bundled synthetic neuron stack (config section `synth`).
#include <cstdio>

#include "apps/cli/cli_support.hpp"
#include "apps/cli/commands_detail.hpp"
#include "io/error.hpp"
#include "io/tiff_stack.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {

io::Volume write_synthetic_stack(const std::filesystem::path& out, const io::SyntheticNeuronOptions& options,
                                 bool quiet) {
  io::Stopwatch watch;
  io::Volume volume = io::make_synthetic_neuron(options);
  io::TiffWriteOptions write;
  write.type = io::SampleType::kUint16;
  write.spacing_um = options.spacing_um;
  io::write_tiff_stack(out, volume, write);
  if (!quiet) {
    std::printf("synth: wrote %s: Z=%d Y=%d X=%d uint16, spacing %.4g x %.4g x %.4g um, seed %llu (%s)\n",
                out.c_str(), volume.nz, volume.ny, volume.nx, options.spacing_um[0], options.spacing_um[1],
                options.spacing_um[2], static_cast<unsigned long long>(options.seed),
                format_seconds(watch.elapsed()).c_str());
  }
  return volume;
}

void add_synth_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("synth", "write a realistic synthetic neuron stack (uint16 TIFF)");
  struct Args {
    std::string out;
    std::optional<std::uint64_t> seed;
    std::vector<int> shape_zyx;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("-o,--output", args->out, "output TIFF path")->required();
  cmd->add_option("--seed", args->seed, "random seed (default from config: synth.seed)");
  cmd->add_option("--shape", args->shape_zyx, "stack shape Z,Y,X (default from config)")->delimiter(',');
  cmd->callback([args, &global] {
    io::SyntheticNeuronOptions options = global.config().synth;
    if (args->seed) options.seed = *args->seed;
    if (!args->shape_zyx.empty()) {
      if (args->shape_zyx.size() != 3) {
        throw io::InputError("--shape: expected 3 values Z,Y,X, got " + std::to_string(args->shape_zyx.size()));
      }
      options.nz = args->shape_zyx[0];
      options.ny = args->shape_zyx[1];
      options.nx = args->shape_zyx[2];
    }
    options.validate();
    write_synthetic_stack(args->out, options, global.quiet);
  });
}

}  // namespace hisnegs::apps
