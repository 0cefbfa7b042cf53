// SPDX-License-Identifier: Apache-2.0
// tile_stacks: a large test stack made of real ones, for the memory and time
// benchmarks of docs/benchmarks.md (a 1024 × 1024 × 100 stack made by tiling
// the shared volumes).
//
//   tile_stacks OUT.tif Z,Y,X IN.tif [IN.tif ...]
//
// The output (uint8 when every input is uint8, else uint16, else float32) is a
// grid of tiles, row by row; tile i is input i mod N, mirrored in x on every
// second pass through the inputs so that repeats are not copies. Each input is
// placed at the tile's corner, cropped to the tile and to Z pages, zero where it
// is smaller. The tile is the largest input's X × Y. Spacing: the first input's.
#include <algorithm>
#include <cstdio>
#include <exception>
#include <string>
#include <vector>

#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/tiff_stack.hpp"

namespace {

using hisnegs::io::InputError;

std::vector<int> parse_shape(const std::string& text) {
  std::vector<int> v;
  std::size_t at = 0;
  while (at <= text.size()) {
    const std::size_t comma = std::min(text.find(',', at), text.size());
    const std::string part = text.substr(at, comma - at);
    std::size_t used = 0;
    int value = 0;
    try {
      value = std::stoi(part, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (used == 0 || used != part.size() || value < 1 || value > 65536) {
      throw InputError("shape " + text + ": expected Z,Y,X, each an integer in [1, 65536]");
    }
    v.push_back(value);
    at = comma + 1;
  }
  if (v.size() != 3) throw InputError("shape " + text + ": expected 3 values Z,Y,X");
  return v;
}

int run(int argc, char** argv) {
  if (argc < 4) {
    std::fprintf(stderr, "usage: tile_stacks OUT.tif Z,Y,X IN.tif [IN.tif ...]\n");
    return 2;
  }
  const std::string out = argv[1];
  const std::vector<int> shape = parse_shape(argv[2]);
  const int nz = shape[0], ny = shape[1], nx = shape[2];
  std::vector<hisnegs::io::Volume> inputs;
  for (int i = 3; i < argc; ++i) {
    if (hisnegs::io::same_file(out, argv[i]))
      throw InputError(out + ": is input " + argv[i] + "; refusing to overwrite it");
    inputs.push_back(hisnegs::io::read_tiff_stack(argv[i]));
  }
  int tile_x = 0, tile_y = 0;
  hisnegs::io::SampleType type = hisnegs::io::SampleType::kUint8;
  for (const hisnegs::io::Volume& v : inputs) {
    tile_x = std::max(tile_x, v.nx);
    tile_y = std::max(tile_y, v.ny);
    if (v.stored_as == hisnegs::io::SampleType::kFloat32) {
      type = hisnegs::io::SampleType::kFloat32;
    } else if (v.stored_as == hisnegs::io::SampleType::kUint16 && type == hisnegs::io::SampleType::kUint8) {
      type = hisnegs::io::SampleType::kUint16;
    }
  }
  std::vector<float> voxels(static_cast<std::size_t>(nx) * ny * nz, 0.0f);
  const int columns = (nx + tile_x - 1) / tile_x, rows = (ny + tile_y - 1) / tile_y;
  for (int t = 0; t < columns * rows; ++t) {
    const hisnegs::io::Volume& v = inputs[static_cast<std::size_t>(t) % inputs.size()];
    const bool mirror = (t / static_cast<int>(inputs.size())) % 2 == 1;
    const int x0 = (t % columns) * tile_x, y0 = (t / columns) * tile_y;
    for (int z = 0; z < std::min(nz, v.nz); ++z) {
      for (int y = 0; y < std::min(v.ny, ny - y0); ++y) {
        for (int x = 0; x < std::min(v.nx, nx - x0); ++x) {
          voxels[(static_cast<std::size_t>(z) * ny + y0 + y) * nx + x0 + x] = v.at(mirror ? v.nx - 1 - x : x, y, z);
        }
      }
    }
  }
  hisnegs::io::TiffWriteOptions options;
  options.type = type;
  options.spacing_um = inputs.front().spacing.um;
  hisnegs::io::write_tiff_stack(out, voxels, nx, ny, nz, options);
  std::fprintf(stderr, "tile_stacks: wrote %s: %d x %d x %d (Z x Y x X), %d x %d tiles of %d x %d\n", out.c_str(), nz,
               ny, nx, rows, columns, tile_y, tile_x);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tile_stacks: %s\n", e.what());
    return 2;
  }
}
