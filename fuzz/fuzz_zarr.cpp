// SPDX-License-Identifier: Apache-2.0
// libFuzzer target for the Zarr reader: the input is an array's metadata (.zarray,
// or zarr.json when it names zarr_format 3), a NUL, then the bytes of its first
// chunk (v2 key 0.0.0, v3 key c/0/0/0, a shard when the codecs say so). The folder
// is read with inspect_stack and load_volume. Only io::InputError may escape.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>

#include "fuzz/fuzz_support.hpp"
#include "io/load_volume.hpp"
#include "io/stack_file.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  setenv("HISNEGS_MAX_ALLOC_GB", "0.0625", 1);  // as fuzz_tiff: hostile shapes refused before allocating
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace hisnegs;
  const auto* nul = static_cast<const std::uint8_t*>(std::memchr(data, 0, size));
  const std::size_t meta_size = nul ? static_cast<std::size_t>(nul - data) : size;
  const std::string meta(reinterpret_cast<const char*>(data), meta_size);
  const bool v3 = meta.find("\"zarr_format\": 3") != std::string::npos || meta.find("\"zarr_format\":3") != std::string::npos;
  const std::filesystem::path folder = fuzz::scratch_dir() / "a.zarr";
  std::error_code ec;
  std::filesystem::remove_all(folder, ec);
  std::filesystem::create_directories(folder / "c" / "0" / "0");
  (void)fuzz::write_input(v3 ? "a.zarr/zarr.json" : "a.zarr/.zarray", data, meta_size);
  const std::uint8_t* chunk = nul ? nul + 1 : data + size;
  (void)fuzz::write_input(v3 ? "a.zarr/c/0/0/0" : "a.zarr/0.0.0", chunk, static_cast<std::size_t>(data + size - chunk));
  try {
    const io::StackHeader h = io::inspect_stack(folder);
    io::VolumeOptions options;
    if (h.channels > 1) options.channel = h.channels - 1;
    const io::LoadedVolume loaded = io::load_volume(folder, options);
    const io::Volume& v = loaded.volume;
    fuzz::require(v.nx == h.nx && v.ny == h.ny && v.nz == h.nz, "load_volume shape == inspect_stack shape");
    for (float x : v.voxels) fuzz::require(x >= 0.0f && x <= 1.0f, "normalized voxels lie in [0, 1]");
    for (int a = 0; a < 3; ++a) {
      const double s = v.spacing.um[static_cast<std::size_t>(a)];
      fuzz::require(std::isfinite(s) && s > 0, "spacing is finite and > 0");
    }
  } catch (const io::InputError& e) {
    fuzz::check_input_error(e);
  }
  return 0;
}
