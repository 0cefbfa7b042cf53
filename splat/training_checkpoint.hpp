// SPDX-License-Identifier: Apache-2.0
// The checkpoints of a training run (RUNDIR/checkpoints): each epoch's model and
// optimizer state as a pair of files plus `latest`, written so a crash at any point
// leaves a complete pair to resume from, and resuming from them.
#pragma once

#include <filesystem>

#include "gmf/core/checkpoint.hpp"
#include "splat/trainer.hpp"

namespace hisnegs::splat {

// RUNDIR/checkpoints files: epoch_NNNNN.ply, state_NNNNN.bin, and `latest` (one line
// "NNNNN"), each written atomically in that order, so `latest` always names a complete pair.
[[nodiscard]] std::filesystem::path checkpoint_ply_path(const std::filesystem::path& checkpoint_dir, int epoch);
[[nodiscard]] std::filesystem::path checkpoint_state_path(const std::filesystem::path& checkpoint_dir, int epoch);
// Writes the trainer's parameters (with `meta`) and state for epoch trainer.epoch().
void save_training_checkpoint(const std::filesystem::path& checkpoint_dir, const Trainer& trainer,
                              const gmf::CheckpointMeta& meta);
// Restores the pair `latest` names into `trainer`; returns its epoch. Throws io::InputError
// naming the file when `latest` is missing or malformed or the pair is unusable.
int resume_training(const std::filesystem::path& checkpoint_dir, Trainer& trainer);

}  // namespace hisnegs::splat
