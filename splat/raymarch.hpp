// SPDX-License-Identifier: Apache-2.0
// Ground-truth MIP ray marching on the CPU (TBB over 16x16 pixel tiles) with
// brick-level empty-space skipping, plus the plain double-precision reference
// that defines the result. The per-pixel math is splat/raymarch_kernel.hpp,
// shared with the CUDA back end (splat/cuda/raymarch.cu).
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <span>
#include <vector>

#include "io/volume.hpp"
#include "splat/camera.hpp"
#include "splat/raymarch_kernel.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::splat {

// Sampling step h of exact mode: step_voxels × the smallest world voxel size.
[[nodiscard]] double exact_step(const io::WorldFrame& frame, const RaymarchOptions& options);

// The kernel's parameters for a stack in `frame` whose normalized maximum is
// `global_max` (a pixel that reaches it stops early).
[[nodiscard]] kernels::MarchParams march_params(const io::WorldFrame& frame, const RaymarchOptions& options,
                                                float global_max);

// A normalized volume prepared for marching: its brick maxima and the kernel
// parameters. Keeps a reference to `volume`, which must outlive it.
class RayMarcher {
 public:
  // Throws io::InputError if options are invalid or the volume is empty.
  RayMarcher(const io::Volume& volume, const io::WorldFrame& frame, const RaymarchOptions& options);

  // Renders `view` into `out` (K.height rows of K.width floats). Parallel over tiles; no allocation.
  void render(const Intrinsics& K, const CameraView& view, std::span<float> out) const;

  [[nodiscard]] const kernels::MarchParams& params() const { return params_; }
  [[nodiscard]] kernels::DenseVolume dense() const;
  [[nodiscard]] kernels::BrickMax bricks() const;
  [[nodiscard]] const std::vector<float>& brick_max() const { return brick_max_; }
  [[nodiscard]] double nonempty_brick_fraction() const;

 private:
  const io::Volume* volume_;
  std::vector<float> brick_max_;
  int bx_, by_, bz_;
  kernels::MarchParams params_{};
};

// Per-view constants of the kernel.
[[nodiscard]] kernels::RayView make_ray_view(const Intrinsics& K, const CameraView& view);

// The definition, in double precision and without skipping: every sample of the
// mode along the ray from `origin` with unit direction `dir`, io::sample_trilinear
// at each, the max (0 if the ray misses the box).
[[nodiscard]] double march_ray_reference(const io::Volume& volume, const io::WorldFrame& frame,
                                         const RaymarchOptions& options, const Eigen::Vector3d& origin,
                                         const Eigen::Vector3d& dir);
// A brute-force march of the same ray with a fixed step (world units) over its box segment.
[[nodiscard]] double march_ray_fixed_step(const io::Volume& volume, const io::WorldFrame& frame,
                                          const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double step);

// The ray's segment [t_in, t_out] inside the world box (t >= 0); false if it misses.
bool ray_box_segment(const io::WorldFrame& frame, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir,
                     double& t_in, double& t_out);

}  // namespace hisnegs::splat
