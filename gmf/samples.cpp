// SPDX-License-Identifier: Apache-2.0
// extract_samples: visit the SparseGrid's active leaves, group each leaf's voxels into blocks.
#include "gmf/samples.hpp"

#include <cmath>
#include <span>
#include <stdexcept>
#include <vector>

namespace hisnegs::gmf {

SampleSet extract_samples(const io::SparseGrid& grid, double background_weight, int block) {
  if (block != 1 && block != 2 && block != 4 && block != 8) {
    throw std::invalid_argument("extract_samples: block must be 1, 2, 4 or 8");
  }
  SampleSet out;
  out.block = block;
  const io::WorldFrame frame = grid.frame();
  const double fraction = grid.meta().options.background_fraction;
  const double bg_weight = fraction > 0 ? std::sqrt(background_weight / fraction) : 0.0;
  const int per_leaf = 8 / block;  // blocks per leaf edge
  std::vector<std::vector<io::ActiveVoxel>> groups(static_cast<std::size_t>(per_leaf) * per_leaf * per_leaf);
  auto add_leaf = [&](const std::array<int, 3>& o, std::span<const io::ActiveVoxel> voxels, double weight,
                      std::int64_t& counter) {
    for (auto& gr : groups) gr.clear();
    for (const io::ActiveVoxel& v : voxels) {
      const int cx = v.index[0] - o[0], cy = v.index[1] - o[1], cz = v.index[2] - o[2];
      groups[((cz / block) * per_leaf + cy / block) * per_leaf + cx / block].push_back(v);
    }
    for (const auto& gr : groups) {
      if (gr.empty()) continue;
      const std::array<int, 3>& c0 = gr.front().index;
      out.block_begin.push_back(static_cast<std::uint32_t>(out.size()));
      out.block_origin.push_back({o[0] + (c0[0] - o[0]) / block * block, o[1] + (c0[1] - o[1]) / block * block,
                                  o[2] + (c0[2] - o[2]) / block * block});
      for (const io::ActiveVoxel& v : gr) {
        const Eigen::Vector3d p = frame.world_from_index(Eigen::Vector3d(v.index[0], v.index[1], v.index[2]));
        out.x.push_back(p.x());
        out.y.push_back(p.y());
        out.z.push_back(p.z());
        out.value.push_back(v.value);
        out.weight.push_back(weight);
        ++counter;
      }
    }
  };
  grid.visit_active_leaves(io::SparseGridPart::kForeground,
                           [&](const auto& o, auto voxels) { add_leaf(o, voxels, 1.0, out.foreground); });
  if (bg_weight > 0) {
    grid.visit_active_leaves(io::SparseGridPart::kBackground,
                             [&](const auto& o, auto voxels) { add_leaf(o, voxels, bg_weight, out.background); });
  }
  out.block_begin.push_back(static_cast<std::uint32_t>(out.size()));
  return out;
}

}  // namespace hisnegs::gmf
