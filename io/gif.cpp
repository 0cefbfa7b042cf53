// SPDX-License-Identifier: Apache-2.0
// giflib encoding of Image8 frames (grey map or fixed RGB palette, loop and delay
// extensions) into memory, and slurp-mode decoding for read_gif / inspect_gif.
#include "io/gif.hpp"

#include <gif_lib.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string>
#include <utility>

#include "io/atomic_file.hpp"
#include "io/error.hpp"

namespace hisnegs::io {
namespace {

// Cube levels of the RGB palette; green gets one more level because the eye
// separates greens best (the usual 6x7x6 split of a 256-entry palette).
constexpr int kRedLevels = 6, kGreenLevels = 7, kBlueLevels = 6;
constexpr int kCubeColours = kRedLevels * kGreenLevels * kBlueLevels;  // 252
// The cube is neutral only at black and white (green levels are not multiples
// of 51), so the four spare entries hold the greys between them.
constexpr std::array<int, 4> kExtraGreys = {51, 102, 153, 204};
static_assert(kCubeColours + static_cast<int>(kExtraGreys.size()) == 256);

constexpr int kPaletteSize = 256;
constexpr int kMinDelayCs = 2;

std::string gif_error_text(int code) {
  const char* text = GifErrorString(code);
  return text ? std::string(text) : "giflib error " + std::to_string(code);
}

std::string size_text(const Image8& f) { return std::to_string(f.width) + "x" + std::to_string(f.height); }

// Level i of n spread evenly over 0..255, rounded.
constexpr int level_value(int i, int n) { return (i * 255 * 2 + (n - 1)) / (2 * (n - 1)); }

// Index of the nearest of n even levels to v (the cube is a separable grid, so
// per-axis nearest is the nearest cube colour).
constexpr int nearest_level(int v, int n) { return (v * (n - 1) * 2 + 255) / (2 * 255); }

std::array<GifColorType, kPaletteSize> grey_palette() {
  std::array<GifColorType, kPaletteSize> p{};
  for (int i = 0; i < kPaletteSize; ++i) {
    const auto g = static_cast<GifByteType>(i);
    p[i] = {g, g, g};
  }
  return p;
}

std::array<GifColorType, kPaletteSize> rgb_palette() {
  std::array<GifColorType, kPaletteSize> p{};
  for (int r = 0; r < kRedLevels; ++r) {
    for (int g = 0; g < kGreenLevels; ++g) {
      for (int b = 0; b < kBlueLevels; ++b) {
        p[(r * kGreenLevels + g) * kBlueLevels + b] = {static_cast<GifByteType>(level_value(r, kRedLevels)),
                                                       static_cast<GifByteType>(level_value(g, kGreenLevels)),
                                                       static_cast<GifByteType>(level_value(b, kBlueLevels))};
      }
    }
  }
  for (std::size_t i = 0; i < kExtraGreys.size(); ++i) {
    const auto v = static_cast<GifByteType>(kExtraGreys[i]);
    p[kCubeColours + i] = {v, v, v};
  }
  return p;
}

int squared_distance(int r, int g, int b, const GifColorType& c) {
  const int dr = r - c.Red, dg = g - c.Green, db = b - c.Blue;
  return dr * dr + dg * dg + db * db;
}

// Nearest entry of rgb_palette() to (r, g, b): the per-axis nearest cube colour,
// replaced by an extra grey where that is closer. Exact nearest, ~15 operations.
GifPixelType quantize(int r, int g, int b, const std::array<GifColorType, kPaletteSize>& palette) {
  int best = (nearest_level(r, kRedLevels) * kGreenLevels + nearest_level(g, kGreenLevels)) * kBlueLevels +
             nearest_level(b, kBlueLevels);
  int best_d2 = squared_distance(r, g, b, palette[best]);
  for (int i = kCubeColours; i < kPaletteSize; ++i) {
    const int d2 = squared_distance(r, g, b, palette[i]);
    if (d2 < best_d2) {
      best = i;
      best_d2 = d2;
    }
  }
  return static_cast<GifPixelType>(best);
}

struct EncoderCloser {
  void operator()(GifFileType* gif) const {
    int error = 0;
    EGifCloseFile(gif, &error);  // frees gif whatever it returns
  }
};
using Encoder = std::unique_ptr<GifFileType, EncoderCloser>;

struct DecoderCloser {
  void operator()(GifFileType* gif) const {
    int error = 0;
    DGifCloseFile(gif, &error);  // frees gif whatever it returns
  }
};
using Decoder = std::unique_ptr<GifFileType, DecoderCloser>;

// giflib output callback: appends to the std::vector behind UserData.
int append_bytes(GifFileType* gif, const GifByteType* bytes, int count) {
  auto* out = static_cast<std::vector<std::uint8_t>*>(gif->UserData);
  out->insert(out->end(), bytes, bytes + count);
  return count;
}

void validate_frames(const std::filesystem::path& path, std::span<const Image8> frames, int delay_ms) {
  if (frames.empty()) fail_input(path, "cannot write GIF: no frames");
  if (delay_ms < 0 || delay_ms > kGifMaxDelayMs) {
    fail_input(path, "cannot write GIF: delay_ms " + std::to_string(delay_ms) + " is outside [0, " +
                         std::to_string(kGifMaxDelayMs) + "]");
  }
  const Image8& first = frames.front();
  if (first.width <= 0 || first.height <= 0 || first.width > kGifMaxSide || first.height > kGifMaxSide) {
    fail_input(path, "cannot write GIF: frame size " + size_text(first) + " is outside 1.." +
                         std::to_string(kGifMaxSide) + " per side");
  }
  if (first.channels != 1 && first.channels != 3) {
    fail_input(path, "cannot write GIF: frame 0 has " + std::to_string(first.channels) +
                         " channels, expected 1 (grey) or 3 (RGB)");
  }
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const Image8& f = frames[i];
    const std::string name = "cannot write GIF: frame " + std::to_string(i);
    if (f.width != first.width || f.height != first.height) {
      fail_input(path, name + " is " + size_text(f) + ", frame 0 is " + size_text(first) +
                           " (all frames must be the same size)");
    }
    if (f.channels != first.channels) {
      fail_input(path, name + " has " + std::to_string(f.channels) + " channels, frame 0 has " +
                           std::to_string(first.channels) + " (all frames must match)");
    }
    const std::size_t expected = static_cast<std::size_t>(f.width) * f.height * f.channels;
    if (f.pixels.size() != expected) {
      fail_input(path, name + " has " + std::to_string(f.pixels.size()) + " pixel bytes, expected " +
                           std::to_string(expected));
    }
  }
}

// Throws InputError with giflib's message for the last failed call on `gif`.
[[noreturn]] void fail_gif(const std::filesystem::path& path, const std::string& what, int code) {
  fail_input(path, what + ": " + gif_error_text(code));
}

Decoder open_and_slurp(const std::filesystem::path& path) {
  require_regular_file(path);
  int error = 0;
  Decoder gif(DGifOpenFileName(path.c_str(), &error));
  if (!gif) fail_gif(path, "not a readable GIF", error);
  if (DGifSlurp(gif.get()) != GIF_OK) fail_gif(path, "cannot decode GIF", gif->Error);
  return gif;
}

GraphicsControlBlock control_block(GifFileType* gif, int image) {
  GraphicsControlBlock gcb{};
  gcb.DisposalMode = DISPOSAL_UNSPECIFIED;
  gcb.TransparentColor = NO_TRANSPARENT_COLOR;
  DGifSavedExtensionToGCB(gif, image, &gcb);  // leaves the defaults when the frame has none
  return gcb;
}

bool has_loop_extension(int count, const ExtensionBlock* blocks) {
  for (int i = 0; i < count; ++i) {
    const ExtensionBlock& e = blocks[i];
    if (e.Function == APPLICATION_EXT_FUNC_CODE && e.ByteCount >= 11 &&
        (std::memcmp(e.Bytes, "NETSCAPE2.0", 11) == 0 || std::memcmp(e.Bytes, "ANIMEXTS1.0", 11) == 0)) {
      return true;
    }
  }
  return false;
}

bool is_grey_map(const ColorMapObject* map) {
  if (!map) return true;
  for (int i = 0; i < map->ColorCount; ++i) {
    const GifColorType& c = map->Colors[i];
    if (c.Red != c.Green || c.Green != c.Blue) return false;
  }
  return true;
}

}  // namespace

void write_gif(const std::filesystem::path& path, std::span<const Image8> frames, int delay_ms) {
  validate_frames(path, frames, delay_ms);
  const int width = frames.front().width, height = frames.front().height;
  const bool grey = frames.front().channels == 1;
  const int delay_cs = std::max(kMinDelayCs, (delay_ms + 5) / 10);

  std::vector<std::uint8_t> bytes;
  int error = 0;
  Encoder gif(EGifOpen(&bytes, append_bytes, &error));
  if (!gif) fail_gif(path, "cannot start GIF encoder", error);
  // GIF89a is needed for the loop and delay extensions; giflib only picks it by
  // itself in slurp mode.
  EGifSetGifVersion(gif.get(), true);

  std::array<GifColorType, kPaletteSize> palette = grey ? grey_palette() : rgb_palette();
  const ColorMapObject colour_map{kPaletteSize, 8, false, palette.data()};  // copied by giflib
  if (EGifPutScreenDesc(gif.get(), width, height, 8, 0, &colour_map) != GIF_OK) {
    fail_gif(path, "cannot write GIF screen descriptor", gif->Error);
  }
  // NETSCAPE2.0 application extension: sub-block {1, loop count lo, hi}; 0 = forever.
  const GifByteType loop[3] = {1, 0, 0};
  if (EGifPutExtensionLeader(gif.get(), APPLICATION_EXT_FUNC_CODE) != GIF_OK ||
      EGifPutExtensionBlock(gif.get(), 11, "NETSCAPE2.0") != GIF_OK ||
      EGifPutExtensionBlock(gif.get(), sizeof(loop), loop) != GIF_OK || EGifPutExtensionTrailer(gif.get()) != GIF_OK) {
    fail_gif(path, "cannot write GIF loop extension", gif->Error);
  }

  GraphicsControlBlock gcb{};
  gcb.DisposalMode = DISPOSE_DO_NOT;  // every frame covers the whole canvas anyway
  gcb.UserInputFlag = false;
  gcb.DelayTime = delay_cs;
  gcb.TransparentColor = NO_TRANSPARENT_COLOR;
  GifByteType gcb_bytes[4];
  const auto gcb_size = static_cast<int>(EGifGCBToExtension(&gcb, gcb_bytes));

  // EGifPutLine masks the line in place, so it gets a copy, never the frame.
  std::vector<GifPixelType> row(static_cast<std::size_t>(width));
  for (std::size_t f = 0; f < frames.size(); ++f) {
    const std::string frame = "frame " + std::to_string(f);
    if (EGifPutExtension(gif.get(), GRAPHICS_EXT_FUNC_CODE, gcb_size, gcb_bytes) != GIF_OK) {
      fail_gif(path, "cannot write GIF delay of " + frame, gif->Error);
    }
    if (EGifPutImageDesc(gif.get(), 0, 0, width, height, false, nullptr) != GIF_OK) {
      fail_gif(path, "cannot write GIF image descriptor of " + frame, gif->Error);
    }
    const std::uint8_t* src = frames[f].pixels.data();
    for (int y = 0; y < height; ++y) {
      if (grey) {
        std::memcpy(row.data(), src + static_cast<std::size_t>(y) * width, row.size());
      } else {
        const std::uint8_t* p = src + static_cast<std::size_t>(y) * width * 3;
        for (int x = 0; x < width; ++x, p += 3) row[x] = quantize(p[0], p[1], p[2], palette);
      }
      if (EGifPutLine(gif.get(), row.data(), width) != GIF_OK) {
        fail_gif(path, "cannot encode GIF " + frame, gif->Error);
      }
    }
  }
  if (EGifCloseFile(gif.release(), &error) != GIF_OK) fail_gif(path, "cannot finish GIF", error);
  // Only now touch the disk: a failure above leaves nothing behind.
  write_file_atomic(path, bytes.data(), bytes.size());
}

GifInfo inspect_gif(const std::filesystem::path& path) {
  const Decoder gif = open_and_slurp(path);
  GifInfo info;
  info.width = gif->SWidth;
  info.height = gif->SHeight;
  info.frames = gif->ImageCount;
  if (gif->ImageCount > 0) info.delay_ms = control_block(gif.get(), 0).DelayTime * 10;
  info.loops = has_loop_extension(gif->ExtensionBlockCount, gif->ExtensionBlocks);
  for (int i = 0; i < gif->ImageCount && !info.loops; ++i) {
    const SavedImage& image = gif->SavedImages[i];
    info.loops = has_loop_extension(image.ExtensionBlockCount, image.ExtensionBlocks);
  }
  return info;
}

std::vector<Image8> read_gif(const std::filesystem::path& path) {
  const Decoder gif = open_and_slurp(path);
  const int width = gif->SWidth, height = gif->SHeight;
  if (width <= 0 || height <= 0) {
    fail_input(path,
               "GIF canvas is " + std::to_string(width) + "x" + std::to_string(height) + ", expected at least 1x1");
  }
  bool grey = is_grey_map(gif->SColorMap);
  for (int i = 0; i < gif->ImageCount; ++i) grey = grey && is_grey_map(gif->SavedImages[i].ImageDesc.ColorMap);

  // The canvas starts as the background colour (GIF89a; browsers use
  // transparent instead, which an Image8 cannot hold).
  GifColorType background{0, 0, 0};
  if (gif->SColorMap && gif->SBackGroundColor < gif->SColorMap->ColorCount) {
    background = gif->SColorMap->Colors[gif->SBackGroundColor];
  }
  const std::size_t pixel_count = static_cast<std::size_t>(width) * height;
  std::vector<GifColorType> canvas(pixel_count, background);

  std::vector<Image8> out;
  out.reserve(static_cast<std::size_t>(gif->ImageCount));
  for (int i = 0; i < gif->ImageCount; ++i) {
    const SavedImage& image = gif->SavedImages[i];
    const GifImageDesc& d = image.ImageDesc;
    const std::string frame = "GIF frame " + std::to_string(i);
    const ColorMapObject* map = d.ColorMap ? d.ColorMap : gif->SColorMap;
    if (!map) fail_input(path, frame + " has no colour map");
    if (d.Left < 0 || d.Top < 0 || d.Width <= 0 || d.Height <= 0 || d.Left + d.Width > width ||
        d.Top + d.Height > height || !image.RasterBits) {
      fail_input(path, frame + " rectangle " + std::to_string(d.Width) + "x" + std::to_string(d.Height) + "+" +
                           std::to_string(d.Left) + "+" + std::to_string(d.Top) + " does not fit the " +
                           std::to_string(width) + "x" + std::to_string(height) + " canvas");
    }
    const GraphicsControlBlock gcb = control_block(gif.get(), i);
    std::vector<GifColorType> before;
    if (gcb.DisposalMode == DISPOSE_PREVIOUS) before = canvas;
    for (int y = 0; y < d.Height; ++y) {
      for (int x = 0; x < d.Width; ++x) {
        const int index = image.RasterBits[static_cast<std::size_t>(y) * d.Width + x];
        if (index == gcb.TransparentColor) continue;
        if (index >= map->ColorCount) {
          fail_input(path, frame + " uses colour index " + std::to_string(index) + " past its " +
                               std::to_string(map->ColorCount) + "-entry colour map");
        }
        canvas[static_cast<std::size_t>(d.Top + y) * width + d.Left + x] = map->Colors[index];
      }
    }

    Image8 img;
    img.width = width;
    img.height = height;
    img.channels = grey ? 1 : 3;
    img.pixels.reserve(pixel_count * img.channels);
    for (const GifColorType& c : canvas) {
      img.pixels.push_back(c.Red);
      if (!grey) {
        img.pixels.push_back(c.Green);
        img.pixels.push_back(c.Blue);
      }
    }
    out.push_back(std::move(img));

    if (gcb.DisposalMode == DISPOSE_BACKGROUND) {
      for (int y = 0; y < d.Height; ++y) {
        for (int x = 0; x < d.Width; ++x) {
          canvas[static_cast<std::size_t>(d.Top + y) * width + d.Left + x] = background;
        }
      }
    } else if (gcb.DisposalMode == DISPOSE_PREVIOUS) {
      canvas = std::move(before);
    }
  }
  return out;
}

}  // namespace hisnegs::io
