// Grid initialization, dense rasterization of a mixture and the 3D PSNR.
#include "gmf/init.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "gmf/gaussian_math.hpp"
#include "io/error.hpp"

namespace hisnegs::gmf {
namespace {

struct Cell {
  double wsum = 0, vmax = 0, vsum = 0;
  double px = 0, py = 0, pz = 0;
  int count = 0;
};

std::uint64_t cell_key(const Eigen::Vector3d& p, double cell) {
  const auto c = [&](double v) { return static_cast<std::uint64_t>(static_cast<std::int64_t>(std::floor(v / cell)) + (1 << 20)); };
  return (c(p.x()) << 42) | (c(p.y()) << 21) | c(p.z());
}

}  // namespace

GaussianMixture initialize_on_grid(const io::Volume& volume, const io::WorldFrame& frame, double threshold, int budget,
                                   InitReport* report) {
  std::vector<Eigen::Vector3d> pos;
  std::vector<float> val;
  for (int z = 0; z < volume.nz; ++z)
    for (int y = 0; y < volume.ny; ++y)
      for (int x = 0; x < volume.nx; ++x) {
        const float v = volume.at(x, y, z);
        if (v > threshold) {
          pos.push_back(frame.world_from_index(Eigen::Vector3d(x, y, z)));
          val.push_back(v);
        }
      }
  if (pos.empty()) {
    throw io::InputError(volume.source + ": no voxel above the foreground threshold " + std::to_string(threshold) +
                         "; lower sparse_grid.threshold");
  }
  auto occupied = [&](double cell) {
    std::unordered_map<std::uint64_t, int> cells;
    for (const auto& p : pos) cells[cell_key(p, cell)] = 1;
    return cells.size();
  };
  // Smallest cell whose occupied count fits the budget (count falls as cells grow).
  double lo = frame.voxel_size().minCoeff() * 0.5, hi = 2.0 * frame.aspect().maxCoeff();
  if (occupied(lo) <= static_cast<std::size_t>(budget)) hi = lo;
  for (int it = 0; it < 40 && hi / lo > 1.001; ++it) {
    const double mid = std::sqrt(lo * hi);
    (occupied(mid) <= static_cast<std::size_t>(budget) ? hi : lo) = mid;
  }
  const double cell = hi;
  std::unordered_map<std::uint64_t, Cell> cells;
  for (std::size_t i = 0; i < pos.size(); ++i) {
    Cell& c = cells[cell_key(pos[i], cell)];
    c.wsum += val[i];
    c.vsum += val[i];
    c.vmax = std::max<double>(c.vmax, val[i]);
    c.px += val[i] * pos[i].x();
    c.py += val[i] * pos[i].y();
    c.pz += val[i] * pos[i].z();
    ++c.count;
  }
  // Deterministic order: by key.
  std::vector<std::pair<std::uint64_t, Cell>> sorted(cells.begin(), cells.end());
  std::sort(sorted.begin(), sorted.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  GaussianMixture mixture;
  mixture.reserve(sorted.size());
  const Eigen::Vector3d voxel = frame.voxel_size();
  for (const auto& [key, c] : sorted) {
    GaussianParams g;
    g.mean = {static_cast<float>(c.px / c.wsum), static_cast<float>(c.py / c.wsum), static_cast<float>(c.pz / c.wsum)};
    // σ = half a grid step, but never below half a voxel along an axis.
    for (int a = 0; a < 3; ++a) g.log_scale[a] = static_cast<float>(std::log(std::max(0.5 * cell, 0.5 * voxel[a])));
    g.rotation = {1.0f, 0.0f, 0.0f, 0.0f};
    const double a = std::clamp(c.vsum / c.count, 0.02, 0.98);
    g.intensity_logit = static_cast<float>(std::log(a / (1 - a)));
    mixture.push_back(g);
  }
  if (report) {
    report->cell_world = cell;
    report->foreground = static_cast<std::int64_t>(pos.size());
  }
  return mixture;
}

std::vector<float> rasterize_mixture(const GaussianMixture& mixture, const io::WorldFrame& frame, double cutoff) {
  const Eigen::Vector3i n = frame.shape();
  const std::size_t plane = static_cast<std::size_t>(n.x()) * n.y();
  std::vector<float> out(plane * n.z(), 0.0f);
  // Per Gaussian: frame and index-space box; binned by z slice.
  struct Item {
    GaussianFrame<double> f;
    int lo[3], hi[3];
  };
  std::vector<Item> items(mixture.size());
  std::vector<std::vector<std::uint32_t>> by_slice(n.z());
  for (std::size_t k = 0; k < mixture.size(); ++k) {
    Item& it = items[k];
    it.f = frame_of(mixture[k]);
    const double* mean = it.f.mean;
    double half[3];
    support_half_extents(it.f, cutoff, half);
    const Eigen::Vector3d a = frame.index_from_world(Eigen::Vector3d(mean[0] - half[0], mean[1] - half[1], mean[2] - half[2]));
    const Eigen::Vector3d b = frame.index_from_world(Eigen::Vector3d(mean[0] + half[0], mean[1] + half[1], mean[2] + half[2]));
    for (int d = 0; d < 3; ++d) {
      it.lo[d] = std::max(0, static_cast<int>(std::ceil(a[d])));
      it.hi[d] = std::min(n[d] - 1, static_cast<int>(std::floor(b[d])));
    }
    for (int z = it.lo[2]; z <= it.hi[2]; ++z) by_slice[z].push_back(static_cast<std::uint32_t>(k));
  }
  tbb::parallel_for(tbb::blocked_range<int>(0, n.z()), [&](const tbb::blocked_range<int>& r) {
    for (int z = r.begin(); z != r.end(); ++z) {
      float* slice = out.data() + plane * z;
      for (std::uint32_t k : by_slice[z]) {
        const Item& it = items[k];
        if (it.lo[0] > it.hi[0] || it.lo[1] > it.hi[1]) continue;
        for (int y = it.lo[1]; y <= it.hi[1]; ++y)
          for (int x = it.lo[0]; x <= it.hi[0]; ++x) {
            const Eigen::Vector3d p = frame.world_from_index(Eigen::Vector3d(x, y, z));
            const double xp[3] = {p.x(), p.y(), p.z()};
            double zz[3];
            if (mahalanobis(it.f, xp, zz) > cutoff) continue;
            slice[static_cast<std::size_t>(y) * n.x() + x] += static_cast<float>(evaluate_gaussian<double>(it.f, xp, nullptr));
          }
      }
    }
  });
  return out;
}

double psnr_3d(const std::vector<float>& f, const io::Volume& volume) {
  const double sse = tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, f.size(), 1 << 16), 0.0,
      [&](const tbb::blocked_range<std::size_t>& r, double acc) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) {
          const double d = static_cast<double>(f[i]) - volume.voxels[i];
          acc += d * d;
        }
        return acc;
      },
      std::plus<>());
  const double mse = sse / static_cast<double>(f.size());
  return mse > 0 ? 10.0 * std::log10(1.0 / mse) : 999.0;
}

}  // namespace hisnegs::gmf
