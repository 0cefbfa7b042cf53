// SPDX-License-Identifier: Apache-2.0
// Looping animated GIFs of Image8 frames on giflib (written atomically), and the
// small reader used by tests and `hisnegs info`. Not a general GIF decoder.
#pragma once

#include <filesystem>
#include <span>
#include <vector>

#include "io/png.hpp"

namespace hisnegs::io {

// Longest frame delay a GIF can store: 65535 centiseconds.
inline constexpr int kGifMaxDelayMs = 655350;
// Largest canvas side a GIF can store (16-bit field).
inline constexpr int kGifMaxSide = 65535;

// Writes `frames` as an animated GIF that loops forever, each frame shown for
// `delay_ms` milliseconds, atomically (encoded in memory, then temp file + rename).
//
// Frames: all the same width x height (1..65535 each) and the same channel count.
//  - channels 1 (grey): a 256-entry grey global colour map with index = grey
//    value, so read_gif gives the pixels back exactly.
//  - channels 3 (RGB): quantized to a fixed 256-colour palette: a 6x7x6 RGB cube
//    (levels 51k for red and blue, round(42.5k) for green, which the eye resolves
//    best) plus the greys 51, 102, 153, 204, so a grey ramp stays neutral. Each
//    pixel gets the nearest palette colour (Euclidean RGB); the error is at most
//    sqrt(25^2 + 21^2 + 25^2) ~= 41.1 per pixel (checked over all 2^24 colours),
//    though one channel alone may be off by up to 29 where a grey is nearest.
//    No dithering.
// Delay: GIF stores centiseconds; `delay_ms` is rounded to the nearest and raised
// to 2 cs, the shortest delay browsers honour (they replace 0 and 1 cs by 10 cs).
// Throws InputError naming `path` and the value for: no frames, frames of
// different sizes or channel counts, channels other than 1 or 3, a pixel buffer
// of the wrong length, a side of 0 or > 65535, `delay_ms` outside
// [0, kGifMaxDelayMs], or a giflib failure (with giflib's message). On any
// failure nothing is written and an existing file at `path` is left as it was.
void write_gif(const std::filesystem::path& path, std::span<const Image8> frames, int delay_ms = 40);

// What inspect_gif reports about a GIF file.
struct GifInfo {
  int width = 0, height = 0;  // canvas (logical screen) size in pixels
  int frames = 0;             // number of images in the file
  int delay_ms = 0;           // first frame's delay (0 when it has no graphics control block)
  bool loops = false;         // a NETSCAPE2.0 (or ANIMEXTS1.0) looping extension is present
};

// Reads the structure of a GIF (decodes it, so it costs as much as read_gif).
// Throws InputError naming `path` if it is missing, not a GIF, or corrupt.
GifInfo inspect_gif(const std::filesystem::path& path);

// Decodes every frame of a GIF as the canvas a viewer would show after it
// (frame rectangles, transparency and disposal applied; the canvas starts as the
// background colour). Frames are channels 1 when every colour map in the file is
// grey (R = G = B; the pixel is that level, whatever the palette order), else
// channels 3. Meant for tests and tools, not for untrusted multi-gigabyte files.
// Throws InputError naming `path` if it is missing, not a GIF, corrupt, a frame
// has no colour map or uses an index past its colour map, or a frame rectangle
// leaves the canvas.
std::vector<Image8> read_gif(const std::filesystem::path& path);

}  // namespace hisnegs::io
