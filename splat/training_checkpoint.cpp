// SPDX-License-Identifier: Apache-2.0
// save_training_checkpoint (model, then state, then `latest`) and resume_training.
#include "splat/training_checkpoint.hpp"

#include <cstdio>
#include <string>

#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/fault_injection.hpp"

namespace hisnegs::splat {
namespace {

std::string epoch_tag(int epoch) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%05d", epoch);
  return buf;
}

}  // namespace

std::filesystem::path checkpoint_ply_path(const std::filesystem::path& dir, int epoch) {
  return dir / ("epoch_" + epoch_tag(epoch) + ".ply");
}

std::filesystem::path checkpoint_state_path(const std::filesystem::path& dir, int epoch) {
  return dir / ("state_" + epoch_tag(epoch) + ".bin");
}

void save_training_checkpoint(const std::filesystem::path& dir, const Trainer& trainer,
                              const gmf::CheckpointMeta& meta) {
  const gmf::GaussianMixture mixture = gmf::mixture_from_flat(trainer.params());
  gmf::CheckpointMeta m = meta;
  std::erase_if(m.extra, [](const auto& kv) { return kv.first == "train_epoch"; });
  m.extra.emplace_back("train_epoch", std::to_string(trainer.epoch()));
  // Order matters: a crash leaves `latest` naming the previous complete pair.
  gmf::save_checkpoint(checkpoint_ply_path(dir, trainer.epoch()), mixture, m);
  io::fault_point("checkpoint_write");  // the model is written, its state and `latest` are not yet
  const std::string state = trainer.serialize_state();
  io::write_file_atomic(checkpoint_state_path(dir, trainer.epoch()), state.data(), state.size());
  const std::string latest = epoch_tag(trainer.epoch()) + "\n";
  io::write_file_atomic(dir / "latest", latest.data(), latest.size());
}

int resume_training(const std::filesystem::path& dir, Trainer& trainer) {
  const std::filesystem::path latest = dir / "latest";
  if (!std::filesystem::exists(latest)) io::fail_input(latest, "no checkpoint to resume from (file missing)");
  io::remove_stale_temporaries(dir);  // a write the crash interrupted; `latest` never names one
  const std::string text = io::read_file(latest);
  int epoch = -1;
  char tail = 0;
  if (std::sscanf(text.c_str(), "%d%c", &epoch, &tail) < 1 || epoch < 0 || (tail != 0 && tail != '\n')) {
    io::fail_input(latest, "expected one epoch number, got \"" + io::printable(text, 40) + "\"");
  }
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(checkpoint_ply_path(dir, epoch));
  const auto flat = gmf::flat_params(checkpoint.mixture);
  std::vector<float> params(flat.begin(), flat.end());
  const std::filesystem::path state_path = checkpoint_state_path(dir, epoch);
  trainer.restore_state(io::read_file(state_path), std::move(params), state_path.string());
  if (trainer.epoch() != epoch) io::fail_input(state_path, "holds epoch " + std::to_string(trainer.epoch()));
  return epoch;
}

}  // namespace hisnegs::splat
