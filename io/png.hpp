// SPDX-License-Identifier: Apache-2.0
// 8-bit PNG previews (grey or RGB) on libpng, written atomically, and the
// float -> 8-bit display mapping. Not a general image library.
#pragma once

#include <cstdint>
#include <filesystem>
#include <span>
#include <vector>

namespace hisnegs::io {

// Row-major 8-bit image; channels 1 (grey) or 3 (RGB, interleaved).
struct Image8 {
  int width = 0, height = 0, channels = 1;
  std::vector<std::uint8_t> pixels;  // width * height * channels
};

// Maps values in [lo, hi] linearly to 0..255 for display. Values outside are
// saturated (a preview, not data: the float TIFF beside it keeps the values).
Image8 to_gray8(std::span<const float> values, int width, int height, float lo = 0.0f, float hi = 1.0f);

// Writes `image` as PNG atomically. Throws InputError for a bad shape/channel count.
void write_png(const std::filesystem::path& path, const Image8& image);

// Reads an 8-bit grey or RGB PNG (tests, GIF assembly). Throws InputError naming the file.
Image8 read_png(const std::filesystem::path& path);

}  // namespace hisnegs::io
