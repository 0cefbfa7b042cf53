// SPDX-License-Identifier: Apache-2.0
// extract_samples: visit the SparseGrid's active leaves, group each leaf's voxels into blocks.
#include "gmf/samples.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <span>
#include <stdexcept>
#include <tuple>
#include <vector>

#include "io/hash.hpp"

namespace hisnegs::gmf {
namespace {

// The shell outside the box: for every foreground voxel on a face of the stack,
// the `depth` voxels beyond it along that face's outward normal, value 0 and
// weight 1 (every such voxel is sampled), grouped into blocks of out.block and
// appended as background. Without them nothing stops a Gaussian at the edge of
// the stack from growing out of it, where the ray-marched MIPs see nothing.
void add_outside_samples(const io::SparseGrid& grid, const io::WorldFrame& frame, int depth, SampleSet& out) {
  const Eigen::Vector3i& n = frame.shape();
  std::vector<std::array<int, 3>> outside;
  grid.visit_active_leaves(io::SparseGridPart::kForeground, [&](const auto&, auto voxels) {
    for (const io::ActiveVoxel& v : voxels) {
      for (int a = 0; a < 3; ++a) {
        for (int side = 0; side < 2; ++side) {
          if (v.index[a] != (side == 0 ? 0 : n[a] - 1)) continue;
          for (int d = 1; d <= depth; ++d) {
            std::array<int, 3> p = v.index;
            p[a] = side == 0 ? -d : n[a] - 1 + d;
            outside.push_back(p);
          }
        }
      }
    }
  });
  const int b = out.block;
  const auto block_of = [b](const std::array<int, 3>& p) {
    return std::array<int, 3>{floor_div(p[2], b), floor_div(p[1], b), floor_div(p[0], b)};  // z, y, x
  };
  std::sort(outside.begin(), outside.end(), [&](const auto& p, const auto& q) {
    const auto bp = block_of(p), bq = block_of(q);
    return bp != bq ? bp < bq : std::tie(p[2], p[1], p[0]) < std::tie(q[2], q[1], q[0]);
  });
  outside.erase(std::unique(outside.begin(), outside.end()), outside.end());
  for (std::size_t i = 0; i < outside.size(); ++i) {
    const auto key = block_of(outside[i]);
    if (i == 0 || key != block_of(outside[i - 1])) {
      out.block_begin.push_back(static_cast<std::uint32_t>(out.size()));
      out.block_origin.push_back({key[2] * b, key[1] * b, key[0] * b});
    }
    const Eigen::Vector3d p = frame.world_from_index(Eigen::Vector3d(outside[i][0], outside[i][1], outside[i][2]));
    out.x.push_back(p.x());
    out.y.push_back(p.y());
    out.z.push_back(p.z());
    out.value.push_back(0.0);
    out.weight.push_back(1.0);
    ++out.background;
  }
}

}  // namespace

SampleSet extract_samples(const io::SparseGrid& grid, double background_weight, int block, int outside_voxels) {
  if (block != 1 && block != 2 && block != 4 && block != 8) {
    throw std::invalid_argument("extract_samples: block must be 1, 2, 4 or 8");
  }
  if (outside_voxels < 0 || outside_voxels > 8) {
    throw std::invalid_argument("extract_samples: outside_voxels must be in [0, 8]");
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
  if (outside_voxels > 0) add_outside_samples(grid, frame, outside_voxels, out);
  out.block_begin.push_back(static_cast<std::uint32_t>(out.size()));
  return out;
}

Eigen::Vector3d jitter_reach(const io::WorldFrame& frame, double jitter) { return 0.5 * jitter * frame.voxel_size(); }

SampleSet jitter_samples(const SampleSet& samples, const io::Volume& volume, const io::WorldFrame& frame, double jitter,
                         std::uint64_t seed) {
  if (!(jitter >= 0.0 && jitter <= 1.0)) {
    throw std::invalid_argument("jitter_samples: jitter must be in [0, 1]");
  }
  SampleSet out = samples;
  if (jitter == 0.0) return out;
  const Eigen::Vector3d voxel = frame.voxel_size();
  const std::uint64_t stream = io::splitmix64(seed ^ 0x6A6974746572ULL);  // "jitter"
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, out.size(), 4096), [&](const auto& r) {
    for (std::size_t i = r.begin(); i != r.end(); ++i) {
      const std::uint64_t h = io::splitmix64(stream + 3 * i);
      const auto offset = [&](std::uint64_t k, double size) {
        return (io::unit_double(io::splitmix64(h + k)) - 0.5) * jitter * size;
      };
      out.x[i] += offset(0, voxel.x());
      out.y[i] += offset(1, voxel.y());
      out.z[i] += offset(2, voxel.z());
      out.value[i] = io::sample_trilinear(volume, frame, Eigen::Vector3d(out.x[i], out.y[i], out.z[i]));
    }
  });
  return out;
}

}  // namespace hisnegs::gmf
