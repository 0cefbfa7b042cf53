// SPDX-License-Identifier: Apache-2.0
// `hisnegs noise STACK -o OUT.tif [--background-photons 0.6] [--gain G] [--read-noise S]
// [--offset O] [--shot-noise] [--seed N]`: raw-like test data from a
// background-subtracted stack (apps/simulate/detector_noise.hpp), and what its background
// looks like after normalization, to compare with a raw stack's.
// `hisnegs noise STACK --estimate [--offset O]`: the stack's own Poisson–Gaussian
// parameters (simulate::estimate_detector_noise), in the same units as the options above.
#include <cstdio>

#include "apps/cli/cli_support.hpp"
#include "gmf/core/background.hpp"
#include "apps/simulate/detector_noise.hpp"
#include "io/error.hpp"
#include "io/stack_file.hpp"
#include "io/tiff_stack.hpp"

namespace hisnegs::apps {

void add_noise_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand(
      "noise", "add a microscope's detector noise (Poisson-Gaussian, offset, quantized) to a stack: raw-like test data");
  struct Args {
    std::string in, out;
    simulate::DetectorNoiseOptions noise;
    bool estimate = false;
    VolumeOverrides overrides;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("STACK", args->in, "stack (TIFF or HDF5; counts, e.g. ../shared/data/op1_neuron.tif)")->required();
  cmd->add_option("-o,--output", args->out, "output TIFF (the input's sample type and spacing); required unless --estimate");
  cmd->add_flag("--estimate", args->estimate,
                "measure the stack's gain, read noise and background photons instead (--offset: its known camera bias)");
  cmd->add_option("--background-photons", args->noise.background_photons,
                  "expected background (dark, autofluorescence) photons per voxel")
      ->capture_default_str();
  cmd->add_option("--gain", args->noise.gain, "counts per photon")->capture_default_str();
  cmd->add_option("--read-noise", args->noise.read_noise, "std dev of the read noise, counts")->capture_default_str();
  cmd->add_option("--offset", args->noise.offset, "camera bias, counts")->capture_default_str();
  cmd->add_flag("--shot-noise", args->noise.shot_noise,
                "also resample the stack's values as photons (for a noise-free stack; real stacks carry their own)");
  cmd->add_option("--seed", args->noise.seed, "random seed")->capture_default_str();
  args->overrides.add_to(cmd);
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    args->overrides.apply(config.volume);
    args->noise.validate();
    if (args->estimate) {
      if (!args->out.empty()) throw CLI::ValidationError("--estimate writes nothing: drop -o " + args->out);
      const io::Volume raw = io::read_stack(args->in, io::stack_read_options(config.volume));
      std::printf("noise: %s: %s\n", args->in.c_str(), simulate::estimate_detector_noise(raw, args->noise.offset).describe().c_str());
      return;
    }
    if (args->out.empty()) throw CLI::RequiredError("--output");
    const io::Volume raw = io::read_stack(args->in, io::stack_read_options(config.volume));
    const io::Volume noisy = simulate::add_detector_noise(raw, args->noise);
    io::TiffWriteOptions write;
    write.type = raw.stored_as;
    io::write_tiff_stack(args->out, noisy, write);
    if (global.quiet) return;
    io::Volume normalized = noisy;
    io::normalize(normalized, config.volume.normalization);
    const gmf::BackgroundModel bg = gmf::estimate_background(normalized, config.background);
    std::printf(
        "noise: wrote %s: %s %dx%dx%d with Poisson(%g photons) x gain %g + read noise %g + offset %g%s; after %s "
        "normalization its background (%lld voxels) is %.1f %% zeros, mean %.4g, p99 %.4g\n",
        args->out.c_str(), std::string(io::to_string(raw.stored_as)).c_str(), raw.nx, raw.ny, raw.nz,
        args->noise.background_photons, args->noise.gain, args->noise.read_noise, args->noise.offset,
        args->noise.shot_noise ? ", the stack's values resampled as photons" : "",
        std::string(io::to_string(config.volume.normalization.method)).c_str(), static_cast<long long>(bg.voxels),
        bg.values.empty() || bg.values.front() > 0.0 ? 0.0 : 100.0 * bg.cdf.front(), bg.mean(), bg.quantile(0.99));
  });
}

}  // namespace hisnegs::apps
