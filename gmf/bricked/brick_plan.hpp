// SPDX-License-Identifier: Apache-2.0
// The bricks of a streamed fit (stacks larger than memory): the stack cut into
// cores that tile it, each read with a halo around it. A brick's fit keeps the
// Gaussians whose centres fall in its core; the halo is as wide as such a Gaussian
// can reach, so every voxel a kept Gaussian touches was in the brick's region:
//   halo_axis = ceil(sqrt(δ) s_max / voxel_axis + 1/2)
// for a Gaussian whose largest scale is at most s_max (world units; the fit bounds
// it, GmfOptions::max_scale_world) and whose support is dᵀΣ⁻¹d <= δ (so |d| <=
// sqrt(δ) s_max along any direction); the half voxel is the ownership rule (a centre
// belongs to the voxel whose cell holds it). Geometry only: no voxel is read here.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <string>
#include <vector>

#include "io/volume.hpp"
#include "io/volume_source.hpp"

namespace hisnegs::gmf {

struct StreamBrick {
  int id = 0;                       // position in the plan (z-major, then y, x)
  std::array<int, 3> cell{0, 0, 0};  // brick coordinates (x, y, z)
  io::VoxelBox core;                // the voxels this brick owns
  io::VoxelBox region;              // core + halo, clipped to the stack: what is read
  // 0..7 from the parity of the cell: bricks of one colour share no face, edge or
  // corner, so their seam refits are independent.
  [[nodiscard]] int colour() const { return (cell[0] & 1) | ((cell[1] & 1) << 1) | ((cell[2] & 1) << 2); }
};

struct BrickPlan {
  std::array<int, 3> shape{0, 0, 0};  // stack (x, y, z)
  std::array<int, 3> core{0, 0, 0};   // core edge per axis (the last brick of an axis may be shorter)
  std::array<int, 3> halo{0, 0, 0};
  std::array<int, 3> count{1, 1, 1};  // bricks per axis
  std::vector<StreamBrick> bricks;

  [[nodiscard]] std::size_t largest_region_voxels() const;
  // "3 x 3 x 1 = 9 bricks of core 200 x 200 x 60, halo 25 x 25 x 9 voxels".
  [[nodiscard]] std::string describe() const;
  // The brick whose core owns the world point `p` (its voxel cell, clamped to the
  // stack: a centre outside the box belongs to the brick on that face).
  [[nodiscard]] int owner(const io::WorldFrame& frame, const Eigen::Vector3d& p) const;
};

// The halo (x, y, z voxels) for Gaussians of largest scale `max_scale_world` and
// support δ = `cutoff`, as the header says.
[[nodiscard]] std::array<int, 3> halo_voxels(const io::WorldFrame& frame, double cutoff, double max_scale_world);

// Cores of `core` voxels (per axis, each >= 1; an axis shorter than its core is one
// brick) tiling a stack of `shape` (x, y, z), each with `halo` around it.
[[nodiscard]] BrickPlan plan_bricks(const std::array<int, 3>& shape, const std::array<int, 3>& core,
                                    const std::array<int, 3>& halo);

// The world frame of `region` as a stack of its own that keeps the stack's voxel
// size (a box centred on the world origin, CONVENTIONS' frame of a stack of the
// region's shape with aspect = voxel × shape / 2), and the shift that carries its
// world points to the whole stack's: p_stack = p_region + shift.
struct RegionFrame {
  io::WorldFrame frame;
  Eigen::Vector3d shift = Eigen::Vector3d::Zero();
};
[[nodiscard]] RegionFrame region_frame(const io::WorldFrame& stack, const io::VoxelBox& region);

}  // namespace hisnegs::gmf
