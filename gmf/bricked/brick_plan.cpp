// SPDX-License-Identifier: Apache-2.0
// Brick plans: halo bound, tiling, ownership and the region's own world frame.
#include "gmf/bricked/brick_plan.hpp"

#include <algorithm>
#include <cmath>
#include <stdexcept>

namespace hisnegs::gmf {

std::array<int, 3> halo_voxels(const io::WorldFrame& frame, double cutoff, double max_scale_world) {
  if (!(cutoff > 0) || !(max_scale_world > 0)) throw std::invalid_argument("halo_voxels: cutoff and scale must be > 0");
  std::array<int, 3> halo{};
  const double reach = std::sqrt(cutoff) * max_scale_world;
  for (int a = 0; a < 3; ++a) halo[a] = static_cast<int>(std::ceil(reach / frame.voxel_size()[a] + 0.5));
  return halo;
}

BrickPlan plan_bricks(const std::array<int, 3>& shape, const std::array<int, 3>& core, const std::array<int, 3>& halo) {
  BrickPlan plan;
  plan.shape = shape;
  plan.halo = halo;
  for (int a = 0; a < 3; ++a) {
    if (shape[a] < 1 || core[a] < 1 || halo[a] < 0) throw std::invalid_argument("plan_bricks: bad shape, core or halo");
    plan.core[a] = std::min(core[a], shape[a]);
    plan.count[a] = (shape[a] + plan.core[a] - 1) / plan.core[a];
  }
  int id = 0;
  for (int z = 0; z < plan.count[2]; ++z) {
    for (int y = 0; y < plan.count[1]; ++y) {
      for (int x = 0; x < plan.count[0]; ++x) {
        StreamBrick b;
        b.id = id++;
        b.cell = {x, y, z};
        for (int a = 0; a < 3; ++a) {
          b.core.lo[a] = b.cell[a] * plan.core[a];
          b.core.hi[a] = std::min(shape[a], b.core.lo[a] + plan.core[a]);
          b.region.lo[a] = std::max(0, b.core.lo[a] - halo[a]);
          b.region.hi[a] = std::min(shape[a], b.core.hi[a] + halo[a]);
        }
        plan.bricks.push_back(b);
      }
    }
  }
  return plan;
}

std::size_t BrickPlan::largest_region_voxels() const {
  std::size_t most = 0;
  for (const StreamBrick& b : bricks) most = std::max(most, b.region.voxels());
  return most;
}

std::string BrickPlan::describe() const {
  return std::to_string(count[0]) + " x " + std::to_string(count[1]) + " x " + std::to_string(count[2]) + " = " +
         std::to_string(bricks.size()) + " bricks of core " + std::to_string(core[0]) + " x " +
         std::to_string(core[1]) + " x " + std::to_string(core[2]) + ", halo " + std::to_string(halo[0]) + " x " +
         std::to_string(halo[1]) + " x " + std::to_string(halo[2]) + " voxels";
}

int BrickPlan::owner(const io::WorldFrame& frame, const Eigen::Vector3d& p) const {
  const Eigen::Vector3d ijk = frame.index_from_world(p);
  std::array<int, 3> cell{};
  for (int a = 0; a < 3; ++a) {
    // voxel i owns [i - 1/2, i + 1/2); outside the stack: the brick on that face
    const double v = std::floor(ijk[a] + 0.5);
    const int voxel = static_cast<int>(std::clamp(v, 0.0, static_cast<double>(shape[a] - 1)));
    cell[a] = voxel / core[a];
  }
  return (cell[2] * count[1] + cell[1]) * count[0] + cell[0];
}

RegionFrame region_frame(const io::WorldFrame& stack, const io::VoxelBox& region) {
  const Eigen::Vector3i n(region.hi[0] - region.lo[0], region.hi[1] - region.lo[1], region.hi[2] - region.lo[2]);
  const Eigen::Vector3d& voxel = stack.voxel_size();
  const Eigen::Vector3d aspect = (voxel.array() * n.cast<double>().array() / 2.0).matrix();
  RegionFrame r;
  r.frame = io::WorldFrame(n.x(), n.y(), n.z(), aspect);
  const Eigen::Vector3d lo(region.lo[0], region.lo[1], region.lo[2]);
  r.shift = stack.world_from_index(lo) - r.frame.world_from_index(Eigen::Vector3d::Zero());
  return r;
}

}  // namespace hisnegs::gmf
