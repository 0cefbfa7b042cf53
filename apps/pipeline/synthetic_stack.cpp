// SPDX-License-Identifier: Apache-2.0
// write_synthetic_stack: simulate::make_synthetic_neuron, then a uint16 TIFF with its spacing.
#include "apps/pipeline/synthetic_stack.hpp"

#include "apps/pipeline/format.hpp"
#include "apps/simulate/synthetic_neuron.hpp"
#include "io/tiff_stack.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {

io::Volume write_synthetic_stack(const std::filesystem::path& out, const SyntheticConfig& config,
                                 const Progress& progress) {
  const simulate::SyntheticNeuronOptions& options = config.get<&AppConfig::synth>();
  options.validate();
  io::Stopwatch watch;
  io::Volume volume = simulate::make_synthetic_neuron(options);
  io::TiffWriteOptions write;
  write.type = io::SampleType::kUint16;
  write.spacing_um = options.spacing_um;
  io::write_tiff_stack(out, volume, write);
  progress.say("synth: wrote %s: Z=%d Y=%d X=%d uint16, spacing %.4g x %.4g x %.4g um, seed %llu (%s)", out.c_str(),
               volume.nz, volume.ny, volume.nx, options.spacing_um[0], options.spacing_um[1], options.spacing_um[2],
               static_cast<unsigned long long>(options.seed), format_seconds(watch.elapsed()).c_str());
  return volume;
}

}  // namespace hisnegs::apps
