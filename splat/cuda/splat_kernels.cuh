// SPDX-License-Identifier: Apache-2.0
// Device kernels of the CUDA splatting back end (private to splat/cuda/splat.cu):
// per-Gaussian projection and tile rectangles, (tile, amplitude) key duplication,
// tile ranges, the per-tile forward/backward rasterizers and the per-Gaussian
// projection backward. Host orchestration, buffers and CUB calls live in splat.cu.
//
// All math is splat/splat_math.hpp's; these kernels only decide which (pixel,
// Gaussian) pairs meet and in what order, exactly as splat/splat_cpu.cpp and
// splat/detail/splat_cpu_tiles.cpp do.
#pragma once

#include <cuda_runtime.h>

#include <cmath>
#include <cstdint>

#include "splat/splat_math.hpp"

namespace hisnegs::splat::cuda::kernels {

constexpr int kBlock = kTileSize * kTileSize;  // one thread per pixel of a tile
constexpr int kWarps = kBlock / 32;
constexpr int kBatch = kBlock;  // Gaussians loaded into shared memory at once
constexpr int kGradChunk = 32;  // backward: Gaussians reduced per shared-memory round
constexpr unsigned kFullMask = 0xffffffffu;

// Per-frame constants of the rasterizers.
struct TileParams {
  int width, height;  // image, pixels
  int tiles_x;        // tiles per image row
  KernelSettings k;
};

// Counters of one forward, zeroed before it.
struct FrameCounters {
  unsigned int visible;
  unsigned long long skipped;
};

// Tile rectangle [x0, x1] x [y0, y1] (inclusive, tile units) of a visible Gaussian.
struct TileRect {
  int x0, y0, x1, y1;
};

// 1. One thread per Gaussian: Eq. 2-6 in float, then the tiles whose pixels can
// lie in the ellipse's bounding box (splat_cpu.cpp's rule, pixel centres, one
// pixel of margin). `touched` has count + 1 entries; the last is set to 0 so an
// exclusive scan of it ends in the total.
__global__ void __launch_bounds__(256)
    preprocess_kernel(const float* __restrict__ params, int count, ViewParams<float> view, float cutoff, float low_pass,
                      Splat2D<float>* __restrict__ splats, TileRect* __restrict__ rects,
                      std::uint64_t* __restrict__ touched, FrameCounters* __restrict__ counters) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k == 0) touched[count] = 0;
  if (k >= count) return;
  Splat2D<float> s =
      project_gaussian(params + static_cast<std::size_t>(gmf::kGaussianParamCount) * k, view, cutoff, low_pass);
  std::uint64_t n = 0;
  if (s.visible) {
    // Clamped to [-1, size] before the int conversion (same rectangle, no overflow for
    // huge extents, e.g. δ = 1e6).
    const float w = static_cast<float>(view.width), h = static_cast<float>(view.height);
    const int c0 = max(0, static_cast<int>(ceilf(fmaxf(s.u - s.half_w - 0.5f, -1.0f))) - 1);
    const int c1 = min(view.width - 1, static_cast<int>(floorf(fminf(s.u + s.half_w - 0.5f, w))) + 1);
    const int r0 = max(0, static_cast<int>(ceilf(fmaxf(s.v - s.half_h - 0.5f, -1.0f))) - 1);
    const int r1 = min(view.height - 1, static_cast<int>(floorf(fminf(s.v + s.half_h - 0.5f, h))) + 1);
    if (c0 > c1 || r0 > r1 || !isfinite(s.u) || !isfinite(s.v)) {
      s.visible = false;
    } else {
      const TileRect r{c0 / kTileSize, r0 / kTileSize, c1 / kTileSize, r1 / kTileSize};
      rects[k] = r;
      n = static_cast<std::uint64_t>(r.x1 - r.x0 + 1) * static_cast<std::uint64_t>(r.y1 - r.y0 + 1);
      atomicAdd(&counters->visible, 1u);
    }
  }
  splats[k] = s;
  touched[k] = n;
}

// The low 32 key bits: amplitude descending. a_k = sigmoid(ℓ) is positive, so its
// IEEE bits grow with it and their complement sorts it descending; equal amplitudes
// keep Gaussian-index order because the radix sort is stable and keys are written
// in index order (the scan's order).
__device__ __forceinline__ std::uint32_t amplitude_key(float amplitude) { return ~__float_as_uint(amplitude); }

// 2. One thread per Gaussian: its (tile << 32 | amplitude key, Gaussian id) pairs at
// offsets[k] ...
__global__ void __launch_bounds__(256)
    duplicate_kernel(const Splat2D<float>* __restrict__ splats, const TileRect* __restrict__ rects,
                     const std::uint64_t* __restrict__ offsets, int count, int tiles_x,
                     std::uint64_t* __restrict__ keys, std::uint32_t* __restrict__ ids) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= count || !splats[k].visible) return;
  const TileRect r = rects[k];
  const std::uint64_t low = amplitude_key(splats[k].amplitude);
  std::uint64_t at = offsets[k];
  for (int ty = r.y0; ty <= r.y1; ++ty) {
    for (int tx = r.x0; tx <= r.x1; ++tx) {
      keys[at] = (static_cast<std::uint64_t>(ty * tiles_x + tx) << 32) | low;
      ids[at] = static_cast<std::uint32_t>(k);
      ++at;
    }
  }
}

// 3. One thread per sorted entry: each tile's [begin, end) in the sorted list
// (ranges zeroed before, so tiles without entries stay empty).
__global__ void __launch_bounds__(256)
    tile_ranges_kernel(const std::uint64_t* __restrict__ keys, std::uint32_t entries, uint2* __restrict__ ranges) {
  const std::uint32_t i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= entries) return;
  const std::uint32_t tile = static_cast<std::uint32_t>(keys[i] >> 32);
  if (i == 0 || static_cast<std::uint32_t>(keys[i - 1] >> 32) != tile) ranges[tile].x = i;
  if (i + 1 == entries || static_cast<std::uint32_t>(keys[i + 1] >> 32) != tile) ranges[tile].y = i + 1;
}

// A tile's Gaussians, one batch at a time, as structure of arrays in shared memory.
struct SharedBatch {
  float u[kBatch], v[kBatch], con_a[kBatch], con_b[kBatch], con_c[kBatch], amplitude[kBatch];
  std::uint32_t id[kBatch];

  // Called by every thread of the block between two __syncthreads().
  __device__ void load(const std::uint32_t* ids, const Splat2D<float>* splats, std::uint32_t begin, int n) {
    const int t = threadIdx.y * kTileSize + threadIdx.x;
    if (t < n) {
      const std::uint32_t k = ids[begin + t];
      const Splat2D<float> s = splats[k];
      u[t] = s.u;
      v[t] = s.v;
      con_a[t] = s.con_a;
      con_b[t] = s.con_b;
      con_c[t] = s.con_c;
      amplitude[t] = s.amplitude;
      id[t] = k;
    }
  }
  [[nodiscard]] __device__ Splat2D<float> splat(int j) const {
    Splat2D<float> s{};
    s.u = u[j];
    s.v = v[j];
    s.con_a = con_a[j];
    s.con_b = con_b[j];
    s.con_c = con_c[j];
    s.amplitude = amplitude[j];
    s.visible = true;
    return s;
  }
};

__device__ __forceinline__ float warp_sum(float x) {
  for (int offset = 16; offset > 0; offset >>= 1) x += __shfl_down_sync(kFullMask, x, offset);
  return x;
}

__device__ __forceinline__ unsigned long long warp_sum(unsigned long long x) {
  for (int offset = 16; offset > 0; offset >>= 1) x += __shfl_down_sync(kFullMask, x, offset);
  return x;
}

// 4. One 16x16 block per tile, one thread per pixel. Soft: the online softmax of
// report §9.3 (gmf::softmax_add: one exp per term), skipping a term when even its
// largest possible value β a_k is e^-skip below the pixel's running m — as the
// CPU's forward_tile, but decided per pixel rather than per SIMD chunk. Hard: the
// running max; a Gaussian with a_k <= m cannot raise it, and since the list is
// amplitude-descending neither can any later one, so a block whose pixels are all
// settled stops. Writes m, S, I per pixel (hard: m = I = max g, S = 1 where touched).
template <bool kSoft>
__global__ void __launch_bounds__(kBlock)
    forward_kernel(const uint2* __restrict__ ranges, const std::uint32_t* __restrict__ ids,
                   const Splat2D<float>* __restrict__ splats, TileParams tp, float* __restrict__ m_out,
                   float* __restrict__ S_out, float* __restrict__ I_out, FrameCounters* __restrict__ counters) {
  __shared__ SharedBatch batch;
  const int tile = blockIdx.x;
  const int col = (tile % tp.tiles_x) * kTileSize + threadIdx.x;
  const int row = (tile / tp.tiles_x) * kTileSize + threadIdx.y;
  const bool inside = col < tp.width && row < tp.height;
  const float px = static_cast<float>(col) + 0.5f, py = static_cast<float>(row) + 0.5f;
  const uint2 range = ranges[tile];

  gmf::SoftMaxState<float> st;
  gmf::softmax_init(st);  // hard mode keeps its max in st.m
  unsigned long long skipped = 0;
  bool done = !inside;
  for (std::uint32_t begin = range.x; begin < range.y; begin += kBatch) {
    const int n = static_cast<int>(min(static_cast<std::uint32_t>(kBatch), range.y - begin));
    __syncthreads();
    batch.load(ids, splats, begin, n);
    __syncthreads();
    if (!done) {
      for (int j = 0; j < n; ++j) {
        const Splat2D<float> s = batch.splat(j);
        if constexpr (!kSoft) {
          if (s.amplitude <= st.m) break;  // neither it nor any later one can raise the max
        }
        const float q = splat_distance(s, px, py);
        if (!(q <= tp.k.cutoff)) continue;
        if constexpr (kSoft) {
          if (tp.k.skip_log_weight > 0.0f && tp.k.beta * s.amplitude + tp.k.skip_log_weight < st.m) {
            ++skipped;
            continue;
          }
          gmf::softmax_add(st, s.amplitude * expf(-0.5f * q), tp.k.beta);
        } else {
          st.m = fmaxf(st.m, s.amplitude * expf(-0.5f * q));
        }
      }
      // Hard: every later a_k <= this batch's last one.
      if constexpr (!kSoft) done = st.m >= batch.amplitude[n - 1];
    }
    if constexpr (!kSoft) {
      if (__syncthreads_and(done)) break;
    }
  }

  if (inside) {
    const std::size_t at = static_cast<std::size_t>(row) * tp.width + col;
    if constexpr (kSoft) {
      m_out[at] = st.m;
      S_out[at] = st.S;
      I_out[at] = gmf::softmax_value(st);
    } else {
      const bool touched = st.m > -INFINITY;
      m_out[at] = st.m;
      S_out[at] = touched ? 1.0f : 0.0f;
      I_out[at] = touched ? st.m : 0.0f;
    }
  }
  if constexpr (kSoft) {
    // Block reduction of the skipped terms, one atomic per block.
    __shared__ unsigned long long warp_skipped[kWarps];
    const int t = threadIdx.y * kTileSize + threadIdx.x;
    skipped = warp_sum(skipped);
    if (t % 32 == 0) warp_skipped[t / 32] = skipped;
    __syncthreads();
    if (t == 0) {
      unsigned long long total = 0;
      for (int w = 0; w < kWarps; ++w) total += warp_skipped[w];
      if (total != 0) atomicAdd(&counters->skipped, total);
    }
  }
}

// 5. Soft backward, same layout as forward: each pixel's dL/dg_k = dL/dI · dI/dg_k
// (gmf::softmax_dvalue_dterm from the forward's final m, S, I), turned into the six 2D gradient
// sums by accumulate_pixel_grad, with the CPU backward_tile's skip rule on the final
// m. The sums are reduced over the block (warp shuffles, then across the 8 warps in
// shared memory) kGradChunk Gaussians at a time and added to grads (6 per Gaussian:
// u, v, con_a, con_b, con_c, amplitude) with one atomicAdd per (block, Gaussian, field).
__global__ void __launch_bounds__(kBlock)
    backward_kernel(const uint2* __restrict__ ranges, const std::uint32_t* __restrict__ ids,
                    const Splat2D<float>* __restrict__ splats, TileParams tp, const float* __restrict__ m_in,
                    const float* __restrict__ S_in, const float* __restrict__ I_in, const float* __restrict__ dL_dI_in,
                    float* __restrict__ grads) {
  __shared__ SharedBatch batch;
  __shared__ float partial[kWarps][kGradChunk][6];
  const int tile = blockIdx.x;
  const int t = threadIdx.y * kTileSize + threadIdx.x;
  const int lane = t % 32, warp = t / 32;
  const int col = (tile % tp.tiles_x) * kTileSize + threadIdx.x;
  const int row = (tile / tp.tiles_x) * kTileSize + threadIdx.y;
  const float px = static_cast<float>(col) + 0.5f, py = static_cast<float>(row) + 0.5f;
  // Pixels no Gaussian touched (S = 0) and those with dL/dI = 0 contribute nothing.
  float m = 0.0f, S = 1.0f, I = 0.0f, dL_dI = 0.0f;
  if (col < tp.width && row < tp.height) {
    const std::size_t at = static_cast<std::size_t>(row) * tp.width + col;
    if (S_in[at] > 0.0f) {
      m = m_in[at];
      S = S_in[at];
      I = I_in[at];
      dL_dI = dL_dI_in[at];
    }
  }
  const bool active = dL_dI != 0.0f;
  if (!__syncthreads_or(active)) return;
  const uint2 range = ranges[tile];

  for (std::uint32_t begin = range.x; begin < range.y; begin += kBatch) {
    const int n = static_cast<int>(min(static_cast<std::uint32_t>(kBatch), range.y - begin));
    __syncthreads();
    batch.load(ids, splats, begin, n);
    __syncthreads();
    for (int chunk = 0; chunk < n; chunk += kGradChunk) {
      const int chunk_n = min(kGradChunk, n - chunk);
      for (int jj = 0; jj < chunk_n; ++jj) {
        const Splat2D<float> s = batch.splat(chunk + jj);
        Splat2DGrad<float> g;
        bool term = false;
        if (active) {
          const float q = splat_distance(s, px, py);
          // The forward's skip rule, on the final m (>= the running m the forward saw):
          // the terms dropped here have weight below e^-skip as well.
          term =
              q <= tp.k.cutoff && !(tp.k.skip_log_weight > 0.0f && tp.k.beta * s.amplitude + tp.k.skip_log_weight < m);
          if (term) {
            const float gk = s.amplitude * expf(-0.5f * q);
            accumulate_pixel_grad(s, px, py, dL_dI * gmf::softmax_dvalue_dterm(gk, tp.k.beta, m, S, I), g);
          }
        }
        float sums[6] = {g.u, g.v, g.con_a, g.con_b, g.con_c, g.amplitude};
        if (__any_sync(kFullMask, term)) {
          for (float& x : sums) x = warp_sum(x);
        }
        if (lane == 0) {
          for (int f = 0; f < 6; ++f) partial[warp][jj][f] = sums[f];
        }
      }
      __syncthreads();
      if (t < 6 * chunk_n) {
        const int jj = t / 6, f = t % 6;
        float total = 0.0f;
        for (int w = 0; w < kWarps; ++w) total += partial[w][jj][f];
        if (total != 0.0f) atomicAdd(&grads[6 * static_cast<std::size_t>(batch.id[chunk + jj]) + f], total);
      }
      __syncthreads();
    }
  }
}

// 6. One thread per Gaussian: the 2D gradient sums through the projection to the 11
// parameters in double (project_gaussian<double> for the cache, then
// project_gaussian_backward), written (not added) to dL_dparams; |dL/dμ2D| to
// screen_grad when it is not null. Invisible Gaussians get zeros.
__global__ void __launch_bounds__(128)
    projection_backward_kernel(const float* __restrict__ params, int count, ViewParams<double> view, double cutoff,
                               double low_pass, const Splat2D<float>* __restrict__ splats,
                               const float* __restrict__ grads, float* __restrict__ dL_dparams,
                               float* __restrict__ screen_grad) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= count) return;
  double out[gmf::kGaussianParamCount] = {};
  double screen = 0.0;
  if (splats[k].visible) {
    double p[gmf::kGaussianParamCount];
    for (int i = 0; i < gmf::kGaussianParamCount; ++i)
      p[i] = params[static_cast<std::size_t>(gmf::kGaussianParamCount) * k + i];
    ProjectionCache<double> cache;
    const Splat2D<double> s = project_gaussian(p, view, cutoff, low_pass, &cache);
    if (s.visible) {
      const float* g6 = grads + 6 * static_cast<std::size_t>(k);
      const Splat2DGrad<double> g{g6[0], g6[1], g6[2], g6[3], g6[4], g6[5]};
      project_gaussian_backward(p, view, cache, g, out);
      screen = hypot(g.u, g.v);
    }
  }
  for (int i = 0; i < gmf::kGaussianParamCount; ++i)
    dL_dparams[static_cast<std::size_t>(gmf::kGaussianParamCount) * k + i] = static_cast<float>(out[i]);
  if (screen_grad != nullptr) screen_grad[k] = static_cast<float>(screen);
}

}  // namespace hisnegs::splat::cuda::kernels
