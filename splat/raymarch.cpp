// SPDX-License-Identifier: Apache-2.0
// RayMarcher (brick maxima, TBB tiles over the shared kernel) and the double
// precision reference march.
#include "splat/raymarch.hpp"

#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <stdexcept>

#include "io/error.hpp"

namespace hisnegs::splat {

double exact_step(const io::WorldFrame& frame, const RaymarchOptions& options) {
  return options.step_voxels * frame.voxel_size().minCoeff();
}

RayMarcher::RayMarcher(const io::Volume& volume, const io::WorldFrame& frame, const RaymarchOptions& options)
    : volume_(&volume) {
  options.validate();
  if (volume.voxels.empty()) throw io::InputError(volume.source + ": empty volume");
  using kernels::kBrick;
  bx_ = (volume.nx + kBrick - 1) / kBrick;
  by_ = (volume.ny + kBrick - 1) / kBrick;
  bz_ = (volume.nz + kBrick - 1) / kBrick;
  brick_max_.assign(static_cast<std::size_t>(bx_) * by_ * bz_, 0.0f);
  float global_max = 0.0f;
  for (float v : volume.voxels) global_max = std::max(global_max, v);
  // Influence region of brick b: voxels [8b - 1, 8b + 9] (see raymarch_kernel.hpp).
  tbb::parallel_for(tbb::blocked_range<int>(0, bz_), [&](const tbb::blocked_range<int>& r) {
    for (int bz = r.begin(); bz != r.end(); ++bz) {
      const int z0 = std::max(bz * kBrick - 1, 0), z1 = std::min(bz * kBrick + kBrick + 1, volume.nz - 1);
      for (int by = 0; by < by_; ++by) {
        const int y0 = std::max(by * kBrick - 1, 0), y1 = std::min(by * kBrick + kBrick + 1, volume.ny - 1);
        for (int bx = 0; bx < bx_; ++bx) {
          const int x0 = std::max(bx * kBrick - 1, 0), x1 = std::min(bx * kBrick + kBrick + 1, volume.nx - 1);
          float m = 0.0f;
          for (int z = z0; z <= z1; ++z)
            for (int y = y0; y <= y1; ++y) {
              const float* row = &volume.voxels[volume.index(0, y, z)];
              for (int x = x0; x <= x1; ++x) m = std::max(m, row[x]);
            }
          brick_max_[(static_cast<std::size_t>(bz) * by_ + by) * bx_ + bx] = m;
        }
      }
    }
  });
  params_ = march_params(frame, options, global_max);
}

kernels::MarchParams march_params(const io::WorldFrame& frame, const RaymarchOptions& options, float global_max) {
  kernels::MarchParams mp{};
  const Eigen::Vector3d& scale = frame.voxel_size();
  const Eigen::Vector3d offset = frame.world_from_index(Eigen::Vector3d::Zero());
  for (int a = 0; a < 3; ++a) {
    mp.index_from_world_scale[a] = 1.0 / scale[a];
    mp.index_from_world_offset[a] = offset[a];
  }
  mp.exact = options.mode == RaymarchMode::kExact;
  mp.h = exact_step(frame, options);
  mp.t_first = options.t_near;
  mp.dt = (options.t_far - options.t_near) / (options.samples - 1);
  mp.samples = options.samples;
  mp.global_max = global_max;
  return mp;
}

kernels::DenseVolume RayMarcher::dense() const {
  return {volume_->voxels.data(), volume_->nx, volume_->ny, volume_->nz};
}
kernels::BrickMax RayMarcher::bricks() const { return {brick_max_.data(), bx_, by_, bz_}; }

double RayMarcher::nonempty_brick_fraction() const {
  const auto n = std::count_if(brick_max_.begin(), brick_max_.end(), [](float m) { return m > 0.0f; });
  return static_cast<double>(n) / static_cast<double>(brick_max_.size());
}

kernels::RayView make_ray_view(const Intrinsics& K, const CameraView& view) {
  kernels::RayView p{};
  const Eigen::Matrix3d Rt = view.R_cam_from_world.transpose();
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) p.Rt[3 * r + c] = Rt(r, c);
  const Eigen::Vector3d C = view.center_world();
  for (int a = 0; a < 3; ++a) p.center_world[a] = C[a];
  p.fx = K.fx;
  p.fy = K.fy;
  p.cx = K.cx;
  p.cy = K.cy;
  p.width = K.width;
  p.height = K.height;
  return p;
}

void RayMarcher::render(const Intrinsics& K, const CameraView& view, std::span<float> out) const {
  if (out.size() != static_cast<std::size_t>(K.width) * K.height) {
    throw std::invalid_argument("RayMarcher::render: output has the wrong size");
  }
  const kernels::RayView vp = make_ray_view(K, view);
  const kernels::DenseVolume vol = dense();
  const kernels::BrickMax bricks = this->bricks();
  const kernels::MarchParams mp = params_;
  constexpr int kGrain = 16;  // pixels per side of a TBB work item: neighbouring rays share bricks in cache
  tbb::parallel_for(tbb::blocked_range2d<int>(0, K.height, kGrain, 0, K.width, kGrain),
                    [&](const tbb::blocked_range2d<int>& r) {
                      for (int row = r.rows().begin(); row != r.rows().end(); ++row) {
                        float* line = out.data() + static_cast<std::size_t>(row) * K.width;
                        for (int col = r.cols().begin(); col != r.cols().end(); ++col) {
                          line[col] = kernels::march_pixel(vol, bricks, mp, vp, col, row);
                        }
                      }
                    });
}

bool ray_box_segment(const io::WorldFrame& frame, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir,
                     double& t_in, double& t_out) {
  t_in = 0.0;
  t_out = std::numeric_limits<double>::infinity();
  const Eigen::Vector3d& a = frame.aspect();
  for (int k = 0; k < 3; ++k) {
    if (dir[k] == 0.0) {
      if (std::abs(origin[k]) > a[k]) return false;
      continue;
    }
    double t0 = (-a[k] - origin[k]) / dir[k], t1 = (a[k] - origin[k]) / dir[k];
    if (t0 > t1) std::swap(t0, t1);
    t_in = std::max(t_in, t0);
    t_out = std::min(t_out, t1);
  }
  return t_out > t_in;
}

double march_ray_reference(const io::Volume& volume, const io::WorldFrame& frame, const RaymarchOptions& options,
                           const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) {
  double best = 0.0;
  if (options.mode == RaymarchMode::kReport) {
    for (int i = 0; i < options.samples; ++i) {
      const double t = options.t_near + i * (options.t_far - options.t_near) / (options.samples - 1);
      best = std::max(best, static_cast<double>(io::sample_trilinear(volume, frame, origin + t * dir)));
    }
    return best;
  }
  double t_in = 0, t_out = 0;
  if (!ray_box_segment(frame, origin, dir, t_in, t_out)) return 0.0;
  const double h = exact_step(frame, options);
  for (int i = 0;; ++i) {
    const double t = t_in + (i + 0.5) * h;
    if (t >= t_out) break;
    best = std::max(best, static_cast<double>(io::sample_trilinear(volume, frame, origin + t * dir)));
  }
  return best;
}

double march_ray_fixed_step(const io::Volume& volume, const io::WorldFrame& frame, const Eigen::Vector3d& origin,
                            const Eigen::Vector3d& dir, double step) {
  double t_in = 0, t_out = 0;
  if (!ray_box_segment(frame, origin, dir, t_in, t_out)) return 0.0;
  double best = 0.0;
  for (double t = t_in; t <= t_out; t += step) {
    best = std::max(best, static_cast<double>(io::sample_trilinear(volume, frame, origin + t * dir)));
  }
  return best;
}

}  // namespace hisnegs::splat
