// SPDX-License-Identifier: Apache-2.0
// The CPU rasterizer's per-tile kernels (forward soft/hard, soft backward), SIMD
// across the pixels of a tile row with Google Highway, dispatched at run time to
// the best instruction set. Binning and per-Gaussian work live in splat_cpu.cpp.
#pragma once

#include <cstddef>
#include <cstdint>

#include "splat/splat_math.hpp"

namespace hisnegs::splat::detail {

// One Gaussian's 2D parameters as the tile kernels read them, with the per-Gaussian
// constants their tests would otherwise divide for at every (tile, Gaussian) entry:
// one cache line, read through the tile's id list.
struct alignas(64) PackedSplat {
  float u, v;               // centre, pixels
  float A, B, C;            // conic Σ2D⁻¹ = [[A, B], [B, C]]
  float amp, ln_amp;        // a and ln a
  float inv_A, inv_C, det;  // 1/A, 1/C, A C − B²
};

// One tile's Gaussians: their ids in rasterization order (amplitude descending, so
// the running max settles early) into the frame's packed parameters.
struct TileGaussians {
  const PackedSplat* packed;
  const std::uint32_t* ids;
  int count;
  [[nodiscard]] const PackedSplat& operator[](int i) const { return packed[ids[i]]; }
};

// Tile lists are amplitude descending in this many buckets of a ∈ [0, 1] (the
// binning sorts into them; the kernels' early stop bounds a later entry's a by
// its bucket's upper edge).
inline constexpr int kAmplitudeBuckets = 1024;

struct TileFrame {
  int x0, y0;         // the tile's first pixel
  int width, height;  // pixels of the tile inside the image (<= kTileSize)
  int stride;         // floats per image row
  KernelSettings k;   // the frame's settings (count_skipped only counts in soft mode)
  const float* floor = nullptr;  // image-sized (`stride`), the background term per pixel (hard mode); null: none
};

// Binning, for the tile rows ty0 .. ty0 + rows − 1 (rows <= kBandsAtOnce) of a
// Gaussian's bounding box whose tile columns are [x0, x1]: the columns its δ
// ellipse reaches in each, [tx0[i], tx1[i]] (tx1[i] = −1 when none), the same
// band rule as for_each_ellipse_band (splat_math.hpp) in SIMD across the rows.
// Jobs come in batches (one dispatch for many Gaussians).
inline constexpr int kBandsAtOnce = 8;
struct EllipseBands {
  float u, v, slope, k1, k2, x_right, dy_right;  // EllipseRows<float>
  float pad;                                     // pixels added each side
};
struct BandJob {
  EllipseBands e;
  int ty0, rows, x0, x1;
  std::int16_t* tx0;  // `rows` entries each
  std::int16_t* tx1;
};
void tile_bands(const BandJob* jobs, std::size_t count);

// Renders the tile: writes the per-pixel softmax state m (β-scaled max), S and the
// image value I (all image-sized, row-major, `stride`), and adds the soft-MIP terms
// skipped to `*skipped`. Hard mode writes m = I = max g and S = 1 where touched, a
// pixel's floor b > 0 (frame.floor) one more term g = b; soft mode ignores the floor
// (the renderer takes the max with it after the tiles). `argmax` (image-sized, or
// null): each pixel's largest term's Gaussian id, −1 where none or the floor is.
void forward_tile(const TileFrame& frame, const TileGaussians& gaussians, float* m, float* S, float* I,
                  std::int32_t* argmax, std::int64_t* skipped);

// For each of the tile's Gaussians i, writes its six gradient sums
// (dL/du, dL/dv, dL/dcon_a, dL/dcon_b, dL/dcon_c, dL/damplitude) to grads[6 i ...].
void backward_tile(const TileFrame& frame, const TileGaussians& gaussians, const float* m, const float* S,
                   const float* I, const float* dL_dI, float* grads);

}  // namespace hisnegs::splat::detail
