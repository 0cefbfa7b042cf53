// SPDX-License-Identifier: Apache-2.0
// The synthetic neuron written as a uint16 TIFF stack with its spacing (config
// section synth). The neuron itself is simulate::make_synthetic_neuron.
#pragma once

#include <filesystem>

#include "apps/pipeline/config_slice.hpp"
#include "apps/pipeline/progress.hpp"
#include "io/volume.hpp"

namespace hisnegs::apps {

using SyntheticConfig = ConfigSlice<&AppConfig::synth>;

// Generates the stack, writes it to `out` and returns it; one "synth: wrote ..." line.
io::Volume write_synthetic_stack(const std::filesystem::path& out, const SyntheticConfig& config,
                                 const Progress& progress);

}  // namespace hisnegs::apps
