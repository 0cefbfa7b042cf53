// SPDX-License-Identifier: Apache-2.0
// TrainingData's checks and load_training_data.
#include "splat/training_data.hpp"

#include <stdexcept>
#include <string>

#include "io/error.hpp"
#include "io/tiff_stack.hpp"

namespace hisnegs::splat {

std::span<const float> TrainingData::image(int i) const {
  const std::size_t n = static_cast<std::size_t>(intrinsics.width) * intrinsics.height;
  return std::span<const float>(images).subspan(static_cast<std::size_t>(i) * n, n);
}

void TrainingData::check() const {
  if (views.empty()) throw std::invalid_argument("TrainingData: no views");
  const std::size_t n = static_cast<std::size_t>(intrinsics.width) * intrinsics.height;
  if (images.size() != views.size() * n) {
    throw std::invalid_argument("TrainingData: " + std::to_string(images.size()) + " pixels for " +
                                std::to_string(views.size()) + " views of " + std::to_string(intrinsics.width) + "x" +
                                std::to_string(intrinsics.height));
  }
}

TrainingData load_training_data(const std::filesystem::path& dir) {
  const std::filesystem::path cameras_path = dir / "cameras.json", mips_path = dir / "mips.tif";
  io::require_regular_file(cameras_path);
  io::require_regular_file(mips_path);
  CameraSet cameras = read_cameras_json(cameras_path);
  io::Volume stack = io::read_tiff_stack(mips_path);
  const Intrinsics& K = cameras.intrinsics;
  if (stack.nz != static_cast<int>(cameras.views.size())) {
    io::fail_input(mips_path, std::to_string(stack.nz) + " pages, but " + cameras_path.string() + " has " +
                                  std::to_string(cameras.views.size()) + " views");
  }
  if (stack.nx != K.width || stack.ny != K.height) {
    io::fail_input(mips_path, "pages of " + std::to_string(stack.nx) + "x" + std::to_string(stack.ny) + ", but " +
                                  cameras_path.string() + " gives " + std::to_string(K.width) + "x" +
                                  std::to_string(K.height));
  }
  TrainingData data;
  data.intrinsics = K;
  data.views = std::move(cameras.views);
  data.images = std::move(stack.voxels);
  return data;
}

}  // namespace hisnegs::splat
