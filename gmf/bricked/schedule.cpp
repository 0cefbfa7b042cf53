// SPDX-License-Identifier: Apache-2.0
// brick_ranks, share_of_bricks, the work models, core_foreground_counts and
// reaches_shared_face.
#include "gmf/bricked/schedule.hpp"

#include <algorithm>
#include <array>
#include <cmath>

#include "gmf/core/gaussian_math.hpp"

namespace hisnegs::gmf {

std::vector<int> brick_ranks(const std::vector<int>& ids, int ranks, const std::function<double(int)>& weight) {
  std::vector<int> rank_of(ids.size(), 0);
  if (ranks <= 1) return rank_of;
  // Heaviest first (ties: the lower id), each to the rank with the least so far
  // (ties: the lower rank): the same on every rank, whatever order they run in.
  std::vector<std::size_t> order(ids.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::vector<double> w(ids.size());
  for (std::size_t i = 0; i < ids.size(); ++i) w[i] = weight(ids[i]);
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return w[a] > w[b]; });
  std::vector<double> load(static_cast<std::size_t>(ranks), 0.0);
  for (std::size_t i : order) {
    const auto least = static_cast<std::size_t>(std::min_element(load.begin(), load.end()) - load.begin());
    load[least] += w[i];
    rank_of[i] = static_cast<int>(least);
  }
  return rank_of;
}

std::vector<std::int64_t> core_foreground_counts(const io::VolumeSource& source, const io::Normalization& map,
                                                 const BrickPlan& p, double threshold, std::size_t slab,
                                                 const io::ScanShare& share) {
  std::array<std::vector<std::size_t>, 3> cell;  // per axis, each voxel's brick coordinate
  for (int a = 0; a < 3; ++a) {
    cell[a].resize(static_cast<std::size_t>(p.shape[a]));
    for (int v = 0; v < p.shape[a]; ++v) cell[a][static_cast<std::size_t>(v)] = static_cast<std::size_t>(v / p.core[a]);
  }
  const auto nx = static_cast<std::size_t>(p.count[0]), ny = static_cast<std::size_t>(p.count[1]);
  std::vector<double> counts(p.bricks.size(), 0.0);
  std::vector<float> normalized;  // ~64 Ki values at a time: the slab is the pass's only large buffer
  io::for_each_slab(source, slab, share, [&](const io::VoxelBox& box, std::span<const float> values) {
    const auto width = static_cast<std::size_t>(box.hi[0] - box.lo[0]);
    const auto height = static_cast<std::size_t>(box.hi[1] - box.lo[1]);
    const std::size_t rows = values.size() / width, group = std::max<std::size_t>(1, 65536 / width);
    for (std::size_t r0 = 0; r0 < rows; r0 += group) {
      const std::size_t r1 = std::min(rows, r0 + group);
      normalized.assign(values.begin() + static_cast<std::ptrdiff_t>(r0 * width),
                        values.begin() + static_cast<std::ptrdiff_t>(r1 * width));
      (void)io::apply_normalization(normalized, map);
      for (std::size_t r = r0; r < r1; ++r) {
        const std::size_t z = static_cast<std::size_t>(box.lo[2]) + r / height;
        const std::size_t y = static_cast<std::size_t>(box.lo[1]) + r % height;
        const std::size_t row = (cell[2][z] * ny + cell[1][y]) * nx;
        const float* v = normalized.data() + (r - r0) * width;
        for (std::size_t i = 0; i < width; ++i) {
          if (v[i] > threshold) counts[row + cell[0][static_cast<std::size_t>(box.lo[0]) + i]] += 1.0;
        }
      }
    }
  });
  if (share.shared()) share.sum(counts);  // integers below 2^53: exact
  std::vector<std::int64_t> out(counts.size());
  for (std::size_t id = 0; id < out.size(); ++id) out[id] = std::llround(counts[id]);
  return out;
}

double brick_work(double core_foreground, double core_voxels) { return core_foreground + core_voxels / 4000.0; }

double measure_work(double region_voxels, double gaussians) { return region_voxels + 2000.0 * gaussians; }

bool reaches_shared_face(const BrickPlan& p, const io::WorldFrame& frame, double cutoff, const StreamBrick& b,
                         const GaussianParams& g) {
  const Eigen::Vector3d ijk = frame.index_from_world(Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2]));
  const Eigen::Matrix3d sigma = covariance(g);
  for (int a = 0; a < 3; ++a) {
    const double extent = std::sqrt(cutoff * sigma(a, a)) / frame.voxel_size()[a];  // voxels along axis a
    const double reach = std::min(1.25 * extent + 1.0, static_cast<double>(p.halo[a]));
    if (b.cell[a] > 0 && ijk[a] - (b.core.lo[a] - 0.5) < reach) return true;
    if (b.cell[a] + 1 < p.count[a] && (b.core.hi[a] - 0.5) - ijk[a] < reach) return true;
  }
  return false;
}

std::vector<int> share_of_bricks(const std::vector<int>& todo, const std::function<double(int)>& weight, int rank,
                                 int ranks) {
  const std::vector<int> rank_of = brick_ranks(todo, ranks, weight);
  std::vector<int> mine;
  for (std::size_t i = 0; i < todo.size(); ++i) {
    if (rank_of[i] == rank) mine.push_back(todo[i]);
  }
  return mine;
}

}  // namespace hisnegs::gmf
