// SPDX-License-Identifier: Apache-2.0
// The training views of stage 2: one camera set and its target MIPs, as `hisnegs
// gt` writes them (DIR/cameras.json + DIR/mips.tif), loaded and checked. Not the
// training itself (splat/trainer.hpp).
#pragma once

#include <filesystem>
#include <span>
#include <vector>

#include "splat/camera.hpp"

namespace hisnegs::splat {

// The training views: one camera set and one H x W target image per view
// (row-major, values in [0, 1]), `images` holding view i at [i H W, (i + 1) H W).
struct TrainingData {
  Intrinsics intrinsics;
  std::vector<CameraView> views;
  std::vector<float> images;

  [[nodiscard]] int count() const { return static_cast<int>(views.size()); }
  [[nodiscard]] std::span<const float> image(int i) const;
  // Throws std::invalid_argument when images.size() != views * width * height or there are no views.
  void check() const;
};

// Reads DIR/cameras.json and DIR/mips.tif (float32, page i = view i; `hisnegs gt` writes
// GTDIR/train and GTDIR/eval so). Throws io::InputError, one line naming the file, when
// either is missing or unreadable, the page count differs from the number of views or
// the page size from the cameras' width x height.
[[nodiscard]] TrainingData load_training_data(const std::filesystem::path& dir);

}  // namespace hisnegs::splat
