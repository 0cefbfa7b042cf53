// SPDX-License-Identifier: Apache-2.0
// kDemoProfile and write_demo_volume.
#include "apps/pipeline/demo.hpp"

#include "io/atomic_file.hpp"

namespace hisnegs::apps {

const char* const kDemoProfile =
    R"(# The profile of `hisnegs demo` (built into the program; this copy is checked against it by a test):
# the bundled synthetic neuron through the whole pipeline in a few minutes on a 2-core CPU.
# Overlaid on the defaults (configs/default.yaml). Compared with the defaults: a smaller
# Adam GMF fit (6000 Gaussians, 30 s), and a short training (24 epochs, beta warm-up over
# 8 epochs, density control at epochs 8 and 16) instead of the report's 2000 epochs.
gmf:
  optimizer: adam
  gaussians: 6000
  time_budget_s: 30
  rounds: 4

train:
  epochs: 24
  beta_warmup_epochs: 8
  densify_from: 8
  densify_every: 8
  densify_until: 17
  prune_every: 8
  save_every: 8
)";

std::filesystem::path write_demo_volume(const std::filesystem::path& dir, const SyntheticConfig& config,
                                        const Progress& progress) {
  std::filesystem::create_directories(dir);
  auto tif = dir / "volume.tif";
  const auto fresh = dir / ".volume.new.tif";
  const io::Volume synthetic = write_synthetic_stack(fresh, config, Progress{});
  const bool same = std::filesystem::exists(tif) && io::read_file(tif) == io::read_file(fresh);
  if (same) {
    std::filesystem::remove(fresh);
  } else {
    std::filesystem::rename(fresh, tif);
  }
  progress.say("demo: synthetic neuron %s: X=%d Y=%d Z=%d (%s)", tif.c_str(), synthetic.nx, synthetic.ny, synthetic.nz,
               same ? "unchanged" : "written");
  return tif;
}

}  // namespace hisnegs::apps
