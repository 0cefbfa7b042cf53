// SPDX-License-Identifier: Apache-2.0
// A checkpoint's halos against its own stack (gmf/core/halo.hpp): the stack read
// with the volume options, the model in the frame it records. `info --volume`,
// `eval --volume` and `run`'s evaluation report it.
#pragma once

#include <filesystem>
#include <string>

#include "gmf/core/checkpoint.hpp"
#include "gmf/core/halo.hpp"
#include "io/load_volume.hpp"

namespace hisnegs::apps {

// Throws io::InputError naming `stack` when it is not of the shape the checkpoint
// records (a model of another stack).
[[nodiscard]] gmf::HaloCount count_model_halos(const gmf::Checkpoint& checkpoint, const std::filesystem::path& stack,
                                               const io::VolumeOptions& options);

// "N (x.xx % of K) with a peak above the stack at their centre by more than its
// noise (m)": what `info` and `eval` say of a count.
[[nodiscard]] std::string halo_text(const gmf::HaloCount& count);

// The stacks `run` measures halos against: those whose float32 copy is at most this
// (the evaluation reads the whole stack; a larger one is bricked in the fit).
inline constexpr double kHaloStackBytes = 2.0 * (1u << 30);

}  // namespace hisnegs::apps
