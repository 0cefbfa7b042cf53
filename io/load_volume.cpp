// SPDX-License-Identifier: Apache-2.0
// load_volume: read_tiff_stack + normalize + aspect_scales, per VolumeOptions.
#include "io/load_volume.hpp"

#include <algorithm>
#include <sstream>

#include "io/error.hpp"
#include "io/stack_file.hpp"
#include "io/tiff_stack.hpp"

namespace hisnegs::io {

void VolumeOptions::validate() const {
  normalization.validate();
  if (!spacing_um.empty()) {
    if (spacing_um.size() != 3) {
      fail_option("volume", "spacing_um", std::to_string(spacing_um.size()) + " values", "expected [] or 3 values");
    }
    for (double s : spacing_um) {
      if (const std::string problem = voxel_size_problem(s); !problem.empty()) {
        fail_option("volume", "spacing_um", number_text(s), problem);
      }
    }
    const auto [lo, hi] = std::minmax_element(spacing_um.begin(), spacing_um.end());
    if (*hi / *lo > kMaxSpacingRatio) {
      fail_option("volume", "spacing_um", number_text(*lo) + "," + number_text(*hi),
                  "voxel sizes may differ by a factor of at most " + number_text(kMaxSpacingRatio));
    }
  }
  if (channel < -1) fail_option("volume", "channel", std::to_string(channel), "must be -1 (none) or >= 0");
  if (timepoint < -1) fail_option("volume", "timepoint", std::to_string(timepoint), "must be -1 (none) or >= 0");
  if (level < 0 || level > 64) fail_option("volume", "level", std::to_string(level), "must be in [0, 64] (0: full resolution)");
  if (dataset.size() > 1024) fail_option("volume", "dataset", printable(dataset, 40), "longer than 1024 characters");
  require_in_range("volume", "foreground_threshold", foreground_threshold, 1e-9, 1.0 - 1e-9);
}

TiffReadOptions tiff_read_options(const VolumeOptions& options) {
  TiffReadOptions read;
  if (options.channel >= 0) read.channel = options.channel;
  if (!options.spacing_um.empty()) {
    read.spacing_um = std::array<double, 3>{options.spacing_um[0], options.spacing_um[1], options.spacing_um[2]};
  }
  return read;
}

StackReadOptions stack_read_options(const VolumeOptions& options) {
  StackReadOptions read;
  read.tiff = tiff_read_options(options);
  read.dataset = options.dataset;
  if (options.timepoint >= 0) read.timepoint = options.timepoint;
  read.level = options.level;
  return read;
}

WorldFrame stack_frame(int nx, int ny, int nz, const VoxelSpacing& spacing, AspectMode mode,
                       const std::filesystem::path& path) {
  const Eigen::Vector3d aspect = aspect_scales(nx, ny, nz, spacing, mode);
  if (!aspect.allFinite() || !(aspect.minCoeff() * kMaxSpacingRatio >= 1.0)) {
    fail_input(path, "voxel size " + number_text(spacing.um[0]) + " x " + number_text(spacing.um[1]) + " x " +
                         number_text(spacing.um[2]) + " um makes the stack's box " +
                         number_text(1.0 / aspect.minCoeff()) + " times thinner than it is long (at most " +
                         number_text(kMaxSpacingRatio) + "); give --spacing or --aspect shape");
  }
  return WorldFrame(nx, ny, nz, aspect);
}

LoadedVolume load_volume(const std::filesystem::path& path, const VolumeOptions& options) {
  options.validate();
  return prepare_volume(read_stack(path, stack_read_options(options)), options, path);
}

LoadedVolume prepare_volume(Volume raw, const VolumeOptions& options, const std::filesystem::path& origin) {
  options.validate();
  LoadedVolume out;
  out.volume = std::move(raw);
  if (out.volume.size() == 0 || out.volume.voxels.size() != out.volume.size()) {
    fail_input(origin, "a stack of " + std::to_string(out.volume.nx) + " x " + std::to_string(out.volume.ny) + " x " +
                           std::to_string(out.volume.nz) + " voxels holding " +
                           std::to_string(out.volume.voxels.size()) + " values");
  }
  if (!options.spacing_um.empty()) {
    for (int a = 0; a < 3; ++a) {
      out.volume.spacing.um[static_cast<std::size_t>(a)] = options.spacing_um[static_cast<std::size_t>(a)];
      out.volume.spacing.source[static_cast<std::size_t>(a)] = SpacingSource::kUser;
    }
  }
  normalize(out.volume, options.normalization);
  const Volume& v = out.volume;
  out.frame = stack_frame(v.nx, v.ny, v.nz, v.spacing, options.aspect, origin);
  return out;
}

}  // namespace hisnegs::io
