// extract_samples: walk the leaves of the SparseGrid's grids.
#include "gmf/samples.hpp"

#include <cmath>

#include "io/detail/vdb_grids.hpp"

namespace hisnegs::gmf {

SampleSet extract_samples(const io::SparseGrid& grid, double background_weight) {
  SampleSet out;
  const io::WorldFrame frame = grid.frame();
  const double fraction = grid.meta().options.background_fraction;
  const double bg_weight = fraction > 0 ? std::sqrt(background_weight / fraction) : 0.0;
  auto add_grid = [&](const openvdb::FloatGrid& g, double weight, std::int64_t& counter) {
    for (auto leaf = g.tree().cbeginLeaf(); leaf; ++leaf) {
      if (leaf->onVoxelCount() == 0) continue;
      const openvdb::Coord o = leaf->origin();
      out.brick_begin.push_back(static_cast<std::uint32_t>(out.size()));
      out.brick_origin.push_back({o.x(), o.y(), o.z()});
      for (auto v = leaf->cbeginValueOn(); v; ++v) {
        const openvdb::Coord c = v.getCoord();
        const Eigen::Vector3d p = frame.world_from_index(Eigen::Vector3d(c.x(), c.y(), c.z()));
        out.x.push_back(p.x());
        out.y.push_back(p.y());
        out.z.push_back(p.z());
        out.value.push_back(*v);
        out.weight.push_back(weight);
        ++counter;
      }
    }
  };
  add_grid(*grid.impl().volume, 1.0, out.foreground);
  if (bg_weight > 0) add_grid(*grid.impl().background, bg_weight, out.background);
  out.brick_begin.push_back(static_cast<std::uint32_t>(out.size()));
  return out;
}

}  // namespace hisnegs::gmf
