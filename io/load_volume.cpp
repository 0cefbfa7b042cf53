// SPDX-License-Identifier: Apache-2.0
// load_volume: read_tiff_stack + normalize + aspect_scales, per VolumeOptions.
#include "io/load_volume.hpp"

#include <cmath>
#include <sstream>

#include "io/error.hpp"
#include "io/tiff_stack.hpp"

namespace hisnegs::io {

void VolumeOptions::validate() const {
  normalization.validate();
  if (!spacing_um.empty()) {
    if (spacing_um.size() != 3) {
      fail_option("volume", "spacing_um", std::to_string(spacing_um.size()) + " values", "expected [] or 3 values");
    }
    for (double s : spacing_um) require_positive("volume", "spacing_um", s);
  }
  if (channel < -1) fail_option("volume", "channel", std::to_string(channel), "must be -1 (none) or >= 0");
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

LoadedVolume load_volume(const std::filesystem::path& path, const VolumeOptions& options) {
  options.validate();
  LoadedVolume out;
  out.volume = read_tiff_stack(path, tiff_read_options(options));
  normalize(out.volume, options.normalization);
  const Volume& v = out.volume;
  out.frame = WorldFrame(v.nx, v.ny, v.nz, aspect_scales(v.nx, v.ny, v.nz, v.spacing, options.aspect));
  return out;
}

}  // namespace hisnegs::io
