// SPDX-License-Identifier: Apache-2.0
// Device kernels of the CUDA splatting back end (private to splat/cuda/splat.cu):
// per-Gaussian projection and binning (the CPU's band walk), (tile, amplitude) key duplication,
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
  const float* floor;  // device, width x height: the background term per pixel; null: none
};

// Counters of one forward, zeroed before it.
struct FrameCounters {
  unsigned int visible;
  unsigned long long skipped;
};

// 1. One thread per Gaussian: Eq. 2-6 in float, then the tiles its δ ellipse
// reaches, band by band (splat_math.hpp's splat_tile_rect and for_each_tile_run,
// the CPU back end's binning), counted into touched[k]; the ellipse's rows are kept
// for the duplicate kernel. `touched` has count + 1 entries; the last is set to 0
// so an exclusive scan of it ends in the total.
__global__ void __launch_bounds__(256)
    preprocess_kernel(const float* __restrict__ params, int count, ViewParams<float> view, float cutoff, float low_pass,
                      Splat2D<float>* __restrict__ splats, TileRect* __restrict__ rects,
                      EllipseRows<float>* __restrict__ rows, std::uint64_t* __restrict__ touched,
                      FrameCounters* __restrict__ counters) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k == 0) touched[count] = 0;
  if (k >= count) return;
  Splat2D<float> s =
      project_gaussian(params + static_cast<std::size_t>(gmf::kGaussianParamCount) * k, view, cutoff, low_pass);
  std::uint64_t n = 0;
  if (s.visible) {
    TileRect r;
    if (!splat_tile_rect(s, view.width, view.height, &r)) {
      s.visible = false;
    } else {
      const EllipseRows<float> e = ellipse_rows(s, cutoff, kBinWiden);
      for_each_tile_run(e, r, [&](int, int tx0, int tx1) {
        if (tx1 >= tx0) n += static_cast<std::uint64_t>(tx1 - tx0 + 1);
      });
      rects[k] = r;
      rows[k] = e;
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
                     const EllipseRows<float>* __restrict__ rows, const std::uint64_t* __restrict__ offsets,
                     int count, int tiles_x, std::uint32_t tiles, std::uint64_t* __restrict__ keys,
                     std::uint32_t* __restrict__ ids) {
  const int k = blockIdx.x * blockDim.x + threadIdx.x;
  if (k >= count || !splats[k].visible) return;
  const std::uint64_t low = amplitude_key(splats[k].amplitude);
  std::uint64_t at = offsets[k];
  const std::uint64_t end = offsets[k + 1];
  // The same runs the preprocess counted (same inputs, same code, so the same
  // count). Defensively, never past this Gaussian's slots, and any slot left over is
  // given the tile index `tiles`, which sorts last and which no rasterizer block reads.
  for_each_tile_run(rows[k], rects[k], [&](int ty, int tx0, int tx1) {
    for (int tx = tx0; tx <= tx1 && at < end; ++tx) {
      keys[at] = (static_cast<std::uint64_t>(ty * tiles_x + tx) << 32) | low;
      ids[at] = static_cast<std::uint32_t>(k);
      ++at;
    }
  });
  for (; at < end; ++at) {
    keys[at] = (static_cast<std::uint64_t>(tiles) << 32) | low;
    ids[at] = static_cast<std::uint32_t>(k);
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

// Walks a tile's list [range.x, range.y) kBatch Gaussians at a time: loads each
// batch into shared memory (every thread takes part) and calls fn(n), n the batch's
// size; stops after a batch for which fn returned true in every thread of the block.
template <class Fn>
__device__ void for_each_batch(SharedBatch& batch, const std::uint32_t* ids, const Splat2D<float>* splats,
                               uint2 range, Fn&& fn) {
  for (std::uint32_t begin = range.x; begin < range.y; begin += kBatch) {
    const int n = static_cast<int>(min(static_cast<std::uint32_t>(kBatch), range.y - begin));
    __syncthreads();
    batch.load(ids, splats, begin, n);
    __syncthreads();
    if (__syncthreads_and(fn(n))) break;
  }
}

__device__ __forceinline__ float warp_sum(float x) {
  for (int offset = 16; offset > 0; offset >>= 1) x += __shfl_down_sync(kFullMask, x, offset);
  return x;
}

__device__ __forceinline__ unsigned long long warp_sum(unsigned long long x) {
  for (int offset = 16; offset > 0; offset >>= 1) x += __shfl_down_sync(kFullMask, x, offset);
  return x;
}

// Block reduction of each thread's skipped terms, one atomic per block. Every thread
// of the block calls it (it synchronizes the block).
__device__ __forceinline__ void add_block_skipped(unsigned long long skipped, FrameCounters* __restrict__ counters) {
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

// 4. One 16x16 block per tile, one thread per pixel, in the CPU's two passes
// (splat/detail/splat_cpu_tiles.cpp, ForwardTile):
//   pass 1, both modes: lm = ln of the largest g = a e^{-q/2} over the terms with
//     q <= δ, exact in the log domain (ln g = ln a − q/2). The list is amplitude-
//     descending, so once ln a <= lm no later Gaussian can raise the pixel, and a
//     block whose pixels are all settled stops.
//   pass 2, soft only: with every pixel's final M = β e^{lm} known, S = Σ e^{βg − M}
//     and W = Σ e^{βg − M} g need no rescaling (report §9.3 without the running max),
//     skipping a term when even its largest possible value β a_k is e^-skip below M
//     (with the final M the skip rule culls as much as it ever can), and stopping
//     once that holds for every later Gaussian of every pixel.
// Writes m, S, I per pixel (soft: m = M, I = W / S; hard: m = I = e^{lm}, S = 1
// where touched; m = −∞ where nothing reaches the pixel). In hard mode a floor b > 0
// (tp.floor) is one more term at its pixel, as in the CPU back end, and `arg_out`
// (null: not kept) gets the pixel's argmax Gaussian, the first in list order among
// equals, −1 where none or the floor won (the CPU's LogMaxPass<true>).
template <bool kSoft>
__global__ void __launch_bounds__(kBlock)
    forward_kernel(const uint2* __restrict__ ranges, const std::uint32_t* __restrict__ ids,
                   const Splat2D<float>* __restrict__ splats, TileParams tp, float* __restrict__ m_out,
                   float* __restrict__ S_out, float* __restrict__ I_out, std::int32_t* __restrict__ arg_out,
                   FrameCounters* __restrict__ counters) {
  __shared__ SharedBatch batch;
  const int tile = blockIdx.x;
  const int col = (tile % tp.tiles_x) * kTileSize + threadIdx.x;
  const int row = (tile / tp.tiles_x) * kTileSize + threadIdx.y;
  const bool inside = col < tp.width && row < tp.height;
  const float px = static_cast<float>(col) + 0.5f, py = static_cast<float>(row) + 0.5f;
  const uint2 range = ranges[tile];

  // Hard mode: the floor b > 0, when there is one, is the pixel's first term, ln b in
  // the log max (soft mode takes the max with it on the host: splat_renderer.cpp).
  const float b = !kSoft && inside && tp.floor != nullptr ? tp.floor[static_cast<std::size_t>(row) * tp.width + col]
                                                          : 0.0f;
  // Pass 1: the log max.
  float lm = b > 0.0f ? logf(b) : -INFINITY;
  std::int32_t arg = -1;
  bool done = !inside;
  for_each_batch(batch, ids, splats, range, [&](int n) {
    if (!done) {
      for (int j = 0; j < n; ++j) {
        const float ln_a = logf(batch.amplitude[j]);
        if (ln_a <= lm) break;  // neither it nor any later one can raise the max
        const float q = splat_distance(batch.splat(j), px, py);
        if (q <= tp.k.cutoff && ln_a - 0.5f * q > lm) {
          lm = ln_a - 0.5f * q;
          arg = static_cast<std::int32_t>(batch.id[j]);
        }
      }
      done = lm >= logf(batch.amplitude[n - 1]);  // every later a_k <= this batch's last one
    }
    return done;
  });
  const bool touched = lm > -INFINITY;

  if constexpr (!kSoft) {
    if (inside) {
      const std::size_t at = static_cast<std::size_t>(row) * tp.width + col;
      const float g = touched ? expf(lm) : 0.0f;
      m_out[at] = touched ? g : -INFINITY;
      S_out[at] = touched ? 1.0f : 0.0f;
      I_out[at] = g;
      if (arg_out != nullptr) arg_out[at] = arg;
    }
  } else {
    // Pass 2: the softmax sums against the final M (+∞ where untouched: nothing to add).
    const float M = touched ? tp.k.beta * expf(lm) : INFINITY;
    const bool skipping = tp.k.skip_log_weight > 0.0f;
    float S = 0.0f, W = 0.0f;
    unsigned long long skipped = 0;
    done = !inside || !touched;
    for_each_batch(batch, ids, splats, range, [&](int n) {
      if (!done) {
        for (int j = 0; j < n; ++j) {
          const Splat2D<float> s = batch.splat(j);
          const float q = splat_distance(s, px, py);
          if (!(q <= tp.k.cutoff)) continue;
          if (skipping && tp.k.beta * s.amplitude + tp.k.skip_log_weight < M) {
            if (tp.k.count_skipped) ++skipped;
            continue;
          }
          const float g = s.amplitude * expf(-0.5f * q);
          const float e = expf(tp.k.beta * g - M);
          S += e;
          W += e * g;
        }
        // Every later term would be skipped: stop, unless they are being counted.
        done = skipping && !tp.k.count_skipped && tp.k.beta * batch.amplitude[n - 1] + tp.k.skip_log_weight < M;
      }
      return done;
    });
    if (inside) {
      const std::size_t at = static_cast<std::size_t>(row) * tp.width + col;
      m_out[at] = touched ? M : -INFINITY;
      S_out[at] = S;
      I_out[at] = S > 0.0f ? W / S : 0.0f;
    }
    add_block_skipped(skipped, counters);
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

  for_each_batch(batch, ids, splats, range, [&](int n) {
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
    return false;  // every batch: the gradient needs every term
  });
}

// 5b. Hard backward, one thread per pixel: the max's subgradient, dL/dI to the
// pixel's argmax Gaussian alone (splat_cpu.cpp's hard_grads), added to grads (6 per
// Gaussian) by atomicAdd.
__global__ void __launch_bounds__(256)
    hard_backward_kernel(const Splat2D<float>* __restrict__ splats, const std::int32_t* __restrict__ argmax,
                         const float* __restrict__ dL_dI, int width, int height, float* __restrict__ grads) {
  const int i = blockIdx.x * blockDim.x + threadIdx.x;
  if (i >= width * height) return;
  const std::int32_t k = argmax[i];
  const float dL = dL_dI[i];
  if (k < 0 || dL == 0.0f) return;
  Splat2DGrad<float> g;
  accumulate_pixel_grad(splats[k], static_cast<float>(i % width) + 0.5f, static_cast<float>(i / width) + 0.5f, dL, g);
  float* out = grads + 6 * static_cast<std::size_t>(k);
  atomicAdd(out + 0, g.u);
  atomicAdd(out + 1, g.v);
  atomicAdd(out + 2, g.con_a);
  atomicAdd(out + 3, g.con_b);
  atomicAdd(out + 4, g.con_c);
  atomicAdd(out + 5, g.amplitude);
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
