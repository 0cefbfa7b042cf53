// SPDX-License-Identifier: Apache-2.0
// What `hisnegs demo` runs the pipeline on: its built-in profile (configs/demo.yaml)
// and the bundled synthetic neuron, written so that a second demo reuses the run.
#pragma once

#include <filesystem>

#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/synthetic_stack.hpp"

namespace hisnegs::apps {

// The built-in profile of `hisnegs demo`: configs/demo.yaml verbatim (a test checks
// that they are equal), overlaid on the defaults.
extern const char* const kDemoProfile;

// Writes the synthetic stack to DIR/volume.tif unless an identical file is there:
// the stack is deterministic, and keeping the file (and its modification time) lets
// a second demo reuse the finished stages. One "demo: synthetic neuron ..." line.
std::filesystem::path write_demo_volume(const std::filesystem::path& dir, const SyntheticConfig& config,
                                        const Progress& progress);

}  // namespace hisnegs::apps
