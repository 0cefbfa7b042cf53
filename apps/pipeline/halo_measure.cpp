// SPDX-License-Identifier: Apache-2.0
// count_model_halos (apps/pipeline/halo_measure.hpp).
#include "apps/pipeline/halo_measure.hpp"

#include <cstdio>
#include <optional>
#include <string>

#include "io/error.hpp"

namespace hisnegs::apps {

gmf::HaloCount count_model_halos(const gmf::Checkpoint& checkpoint, const std::filesystem::path& stack,
                                 const io::VolumeOptions& options) {
  const io::LoadedVolume v = io::load_volume(stack, options);
  io::WorldFrame frame = v.frame;
  if (const std::optional<io::WorldFrame> own = gmf::model_frame(checkpoint.meta)) {
    if (own->shape() != v.frame.shape()) {
      const auto text = [](const Eigen::Vector3i& n) {
        return std::to_string(n.x()) + "x" + std::to_string(n.y()) + "x" + std::to_string(n.z());
      };
      io::fail_input(stack, "is " + text(v.frame.shape()) + " voxels (X x Y x Z); the model was fitted to a " +
                                text(own->shape()) + " stack");
    }
    frame = *own;
  }
  return gmf::count_halos(checkpoint.mixture, v.volume, frame, gmf::stack_noise(v.volume));
}

std::string halo_text(const gmf::HaloCount& count) {
  char line[200];
  std::snprintf(line, sizeof line,
                "%zu (%.2f %% of K) with a peak above the stack at their centre by more than its noise (%.3g)",
                count.halos, 100.0 * count.share(), count.noise);
  return line;
}

}  // namespace hisnegs::apps
