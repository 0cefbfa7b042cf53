// SPDX-License-Identifier: Apache-2.0
// libpng read/write of Image8 via png_image (the simplified libpng API).
#include "io/png.hpp"

#include <png.h>

#include <algorithm>
#include <cmath>
#include <string>

#include "io/atomic_file.hpp"
#include "io/error.hpp"

namespace hisnegs::io {

Image8 to_gray8(std::span<const float> values, int width, int height, float lo, float hi) {
  Image8 img;
  img.width = width;
  img.height = height;
  img.channels = 1;
  img.pixels.resize(static_cast<std::size_t>(width) * height);
  const float scale = hi > lo ? 255.0f / (hi - lo) : 0.0f;
  for (std::size_t i = 0; i < img.pixels.size() && i < values.size(); ++i) {
    const float v = std::isfinite(values[i]) ? (values[i] - lo) * scale : 0.0f;
    img.pixels[i] = static_cast<std::uint8_t>(std::clamp(std::lround(v), 0L, 255L));
  }
  return img;
}

void write_png(const std::filesystem::path& path, const Image8& image) {
  if (image.width <= 0 || image.height <= 0 || (image.channels != 1 && image.channels != 3) ||
      image.pixels.size() != static_cast<std::size_t>(image.width) * image.height * image.channels) {
    fail_input(path, "cannot write PNG: bad image shape " + std::to_string(image.width) + "x" +
                         std::to_string(image.height) + "x" + std::to_string(image.channels));
  }
  png_image png{};
  png.version = PNG_IMAGE_VERSION;
  png.width = static_cast<png_uint_32>(image.width);
  png.height = static_cast<png_uint_32>(image.height);
  png.format = image.channels == 1 ? PNG_FORMAT_GRAY : PNG_FORMAT_RGB;
  AtomicFile out(path);
  if (!png_image_write_to_file(&png, out.temp_path().c_str(), 0, image.pixels.data(), 0, nullptr)) {
    const std::string msg = png.message;
    png_image_free(&png);
    throw std::runtime_error(path.string() + ": cannot write PNG: " + msg);
  }
  out.commit();
}

Image8 read_png(const std::filesystem::path& path) {
  require_regular_file(path);
  png_image png{};
  png.version = PNG_IMAGE_VERSION;
  if (!png_image_begin_read_from_file(&png, path.c_str())) fail_input(path, std::string("not a PNG: ") + png.message);
  const bool color = (png.format & PNG_FORMAT_FLAG_COLOR) != 0;
  png.format = color ? PNG_FORMAT_RGB : PNG_FORMAT_GRAY;
  Image8 img;
  img.width = static_cast<int>(png.width);
  img.height = static_cast<int>(png.height);
  img.channels = color ? 3 : 1;
  img.pixels.resize(PNG_IMAGE_SIZE(png));
  if (!png_image_finish_read(&png, nullptr, img.pixels.data(), 0, nullptr)) {
    const std::string msg = png.message;
    png_image_free(&png);
    fail_input(path, "cannot decode PNG: " + msg);
  }
  return img;
}

}  // namespace hisnegs::io
