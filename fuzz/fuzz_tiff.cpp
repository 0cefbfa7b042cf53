// SPDX-License-Identifier: Apache-2.0
// libFuzzer target for the TIFF stack reader: inspect_tiff_stack, then
// load_volume (read_tiff_stack + normalize + world frame) on the same bytes.
// Only io::InputError may escape the readers; anything else is a finding.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "fuzz/fuzz_support.hpp"
#include "io/load_volume.hpp"
#include "io/tiff_stack.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  // 64 MiB per input: hostile headers claiming gigabytes must be refused before
  // anything is allocated (io/memory_limit.hpp), and zero-filling a volume this
  // size still costs only milliseconds per input.
  setenv("HISNEGS_MAX_ALLOC_GB", "0.0625", 1);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace hisnegs;
  const std::filesystem::path path = fuzz::write_input("stack.tif", data, size);
  try {
    const io::TiffStackInfo info = io::inspect_tiff_stack(path);
    io::VolumeOptions options;
    // The last channel, so that channel selection (samples per pixel, ImageJ
    // hyperstacks, OME SizeC) gets decoded too.
    if (info.channels > 1) options.channel = info.channels - 1;
    // Both normalizations, picked by the input's length so either reaches every layout.
    options.normalization.method = size % 2 ? io::NormalizationMethod::kPercentile : io::NormalizationMethod::kMinMax;
    const io::LoadedVolume loaded = io::load_volume(path, options);
    const io::Volume& v = loaded.volume;
    fuzz::require(v.nx == info.nx && v.ny == info.ny && v.nz == info.nz,
                  "load_volume shape == inspect_tiff_stack shape");
    fuzz::require(v.voxels.size() == v.size(), "voxels.size() == nx*ny*nz");
    for (float x : v.voxels) fuzz::require(x >= 0.0f && x <= 1.0f, "normalized voxels lie in [0, 1]");
    for (int a = 0; a < 3; ++a) {
      const double s = v.spacing.um[static_cast<std::size_t>(a)];
      fuzz::require(std::isfinite(s) && s > 0, "spacing is finite and > 0");
      const double h = loaded.frame.aspect()[a];
      fuzz::require(std::isfinite(h) && h > 0 && h <= 1, "aspect half-extents lie in (0, 1]");
    }
  } catch (const io::InputError& e) {
    fuzz::check_input_error(e);
  }
  return 0;
}
