// extract_samples: walk the leaves of the SparseGrid's grids.
#include "gmf/samples.hpp"

#include <cmath>
#include <stdexcept>

#include "io/detail/vdb_grids.hpp"

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
  auto add_grid = [&](const openvdb::FloatGrid& g, double weight, std::int64_t& counter) {
    std::vector<std::vector<openvdb::Coord>> groups(static_cast<std::size_t>(per_leaf) * per_leaf * per_leaf);
    for (auto leaf = g.tree().cbeginLeaf(); leaf; ++leaf) {
      if (leaf->onVoxelCount() == 0) continue;
      const openvdb::Coord o = leaf->origin();
      for (auto& gr : groups) gr.clear();
      for (auto v = leaf->cbeginValueOn(); v; ++v) {
        const openvdb::Coord c = v.getCoord() - o;
        groups[((c.z() / block) * per_leaf + c.y() / block) * per_leaf + c.x() / block].push_back(v.getCoord());
      }
      for (const auto& gr : groups) {
        if (gr.empty()) continue;
        const openvdb::Coord& c0 = gr.front();
        out.brick_begin.push_back(static_cast<std::uint32_t>(out.size()));
        out.brick_origin.push_back({o.x() + (c0.x() - o.x()) / block * block, o.y() + (c0.y() - o.y()) / block * block,
                                    o.z() + (c0.z() - o.z()) / block * block});
        for (const openvdb::Coord& c : gr) {
          const Eigen::Vector3d p = frame.world_from_index(Eigen::Vector3d(c.x(), c.y(), c.z()));
          out.x.push_back(p.x());
          out.y.push_back(p.y());
          out.z.push_back(p.z());
          out.value.push_back(leaf->getValue(c));
          out.weight.push_back(weight);
          ++counter;
        }
      }
    }
  };
  add_grid(*grid.impl().volume, 1.0, out.foreground);
  if (bg_weight > 0) add_grid(*grid.impl().background, bg_weight, out.background);
  out.brick_begin.push_back(static_cast<std::uint32_t>(out.size()));
  return out;
}

}  // namespace hisnegs::gmf
