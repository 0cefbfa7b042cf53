// SPDX-License-Identifier: Apache-2.0
// render_ground_truth_streamed: bricks, the whole marcher's sample sequence per ray,
// ownership of a sample by its voxel, per-pixel max.
#include "splat/streamed_ground_truth.hpp"

#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>

#include "io/error.hpp"
#include "io/timer.hpp"
#include "splat/raymarch.hpp"
#include "splat/raymarch_kernel.hpp"

namespace hisnegs::splat {
namespace {

// One brick: the region (core ± 1 voxel) in memory and the core it owns.
struct Window {
  kernels::DenseVolume region;
  int origin[3];   // global index of the region's voxel 0
  int lo[3], hi[3];  // the core, global voxels [lo, hi)
};

// The max over the samples of one ray that `w` owns (the sequence of march_ray).
float march_window(const Window& w, const int n[3], const kernels::MarchParams& mp, const double o_world[3],
                   const double d_world[3]) {
  double o[3], d[3];
  for (int a = 0; a < 3; ++a) {
    o[a] = (o_world[a] - mp.index_from_world_offset[a]) * mp.index_from_world_scale[a];
    d[a] = d_world[a] * mp.index_from_world_scale[a];
  }
  // The whole box's segment: it fixes t0 and the index range, as in march_ray.
  double t_in = 0.0, t_out = 1.0e300;
  double w_in = 0.0, w_out = 1.0e300;  // the core's cells [lo - 1/2, hi - 1/2)
  for (int a = 0; a < 3; ++a) {
    const double lo = -0.5, hi = n[a] - 0.5, wlo = w.lo[a] - 0.5, whi = w.hi[a] - 0.5;
    if (d[a] == 0.0) {
      if (o[a] < lo || o[a] > hi || o[a] < wlo || o[a] > whi) return 0.0f;
      continue;
    }
    double ta = (lo - o[a]) / d[a], tb = (hi - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t_in = std::max(t_in, ta);
    t_out = std::min(t_out, tb);
    double wa = (wlo - o[a]) / d[a], wb = (whi - o[a]) / d[a];
    if (wa > wb) std::swap(wa, wb);
    w_in = std::max(w_in, wa);
    w_out = std::min(w_out, wb);
  }
  if (!(t_out > t_in)) return 0.0f;
  const kernels::SampleRange sr = kernels::sample_range(mp, t_in, t_out);
  const double t0 = sr.t0, dt = sr.dt;
  const int i_begin = sr.begin, i_end = sr.end;
  // Candidates: the samples near the core's segment (one step of slack each side);
  // each is kept only if its voxel is in the core.
  const int c_begin = std::max(i_begin, static_cast<int>(std::floor((w_in - t0) / dt)) - 1);
  const int c_end = std::min(i_end, static_cast<int>(std::ceil((w_out - t0) / dt)) + 2);
  float best = 0.0f;
  for (int i = c_begin; i < c_end; ++i) {
    const double t = t0 + i * dt;
    float x[3];
    bool owned = true;
    for (int a = 0; a < 3; ++a) {
      const double p = o[a] + t * d[a];
      const double voxel = std::clamp(std::floor(p + 0.5), 0.0, static_cast<double>(n[a] - 1));
      owned = owned && voxel >= w.lo[a] && voxel < w.hi[a];
      // march_ray's float index, clamped to the stack, then into the region (exact)
      x[a] = kernels::clampf(static_cast<float>(p), 0.0f, static_cast<float>(n[a] - 1)) - static_cast<float>(w.origin[a]);
    }
    if (owned) best = std::max(best, kernels::trilinear(w.region, x[0], x[1], x[2]));
  }
  return best;
}

}  // namespace

MipStack render_ground_truth_streamed(const io::VolumeSource& source, const io::Normalization& normalization,
                                      const io::WorldFrame& frame, const CameraSet& cameras,
                                      const RaymarchOptions& options, int core_voxels,
                                      const std::function<void(int, int)>& progress,
                                      const std::function<bool(int brick)>& marches) {
  options.validate();
  if (core_voxels < 1) throw std::invalid_argument("render_ground_truth_streamed: core_voxels must be >= 1");
  const Intrinsics& K = cameras.intrinsics;
  MipStack out;
  out.width = K.width;
  out.height = K.height;
  out.views = static_cast<int>(cameras.views.size());
  out.pixels.assign(static_cast<std::size_t>(out.views) * K.width * K.height, 0.0f);
  out.seconds_per_view.assign(static_cast<std::size_t>(out.views), 0.0);
  const kernels::MarchParams mp = march_params(frame, options, 1.0f);
  std::vector<kernels::RayView> views;
  for (const CameraView& v : cameras.views) views.push_back(make_ray_view(K, v));
  const int n[3] = {source.nx, source.ny, source.nz};
  int count[3];
  for (int a = 0; a < 3; ++a) count[a] = (n[a] + core_voxels - 1) / core_voxels;
  const int bricks = count[0] * count[1] * count[2];
  std::vector<float> voxels;
  int done = 0;
  for (int bz = 0; bz < count[2]; ++bz) {
    for (int by = 0; by < count[1]; ++by) {
      for (int bx = 0; bx < count[0]; ++bx) {
        const int cell[3] = {bx, by, bz};
        if (marches && !marches((bz * count[1] + by) * count[0] + bx)) {
          if (progress) progress(++done, bricks);
          continue;
        }
        Window w{};
        io::VoxelBox region;
        for (int a = 0; a < 3; ++a) {
          w.lo[a] = cell[a] * core_voxels;
          w.hi[a] = std::min(n[a], w.lo[a] + core_voxels);
          region.lo[a] = std::max(0, w.lo[a] - 1);
          region.hi[a] = std::min(n[a], w.hi[a] + 1);
          w.origin[a] = region.lo[a];
        }
        voxels.resize(region.voxels());
        source.read(region, voxels.data());
        (void)io::apply_normalization(voxels, normalization);
        const bool empty = std::none_of(voxels.begin(), voxels.end(), [](float v) { return v > 0.0f; });
        if (!empty) {
          w.region = {voxels.data(), region.hi[0] - region.lo[0], region.hi[1] - region.lo[1],
                      region.hi[2] - region.lo[2]};
          for (int v = 0; v < out.views; ++v) {
            io::Stopwatch watch;
            float* image = out.pixels.data() + static_cast<std::size_t>(v) * K.width * K.height;
            const kernels::RayView& vp = views[static_cast<std::size_t>(v)];
            tbb::parallel_for(tbb::blocked_range2d<int>(0, K.height, 16, 0, K.width, 16),
                              [&](const tbb::blocked_range2d<int>& r) {
                                for (int row = r.rows().begin(); row != r.rows().end(); ++row) {
                                  for (int col = r.cols().begin(); col != r.cols().end(); ++col) {
                                    double dir[3];
                                    kernels::pixel_ray(vp, col, row, dir);
                                    float& px = image[static_cast<std::size_t>(row) * K.width + col];
                                    px = std::max(px, march_window(w, n, mp, vp.center_world, dir));
                                  }
                                }
                              });
            out.seconds_per_view[static_cast<std::size_t>(v)] += watch.elapsed();
          }
        }
        if (progress) progress(++done, bricks);
      }
    }
  }
  out.backend = Backend::kCpu;
  return out;
}

}  // namespace hisnegs::splat
