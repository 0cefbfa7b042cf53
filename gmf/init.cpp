// SPDX-License-Identifier: Apache-2.0
// Grid initialization.
#include "gmf/init.hpp"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "gmf/core/density_ops.hpp"
#include "io/error.hpp"

namespace hisnegs::gmf {
namespace {

struct Cell {
  double wsum = 0, vmax = 0, vsum = 0;
  double px = 0, py = 0, pz = 0;
  int count = 0;
};

// Cells of edge `cell` with a corner at `corner` (world units).
std::uint64_t cell_key(const Eigen::Vector3d& p, const Eigen::Vector3d& corner, double cell) {
  const auto c = [&](double v, double lo) {
    return static_cast<std::uint64_t>(static_cast<std::int64_t>(std::floor((v - lo) / cell)) + (1 << 20));
  };
  return (c(p.x(), corner.x()) << 42) | (c(p.y(), corner.y()) << 21) | c(p.z(), corner.z());
}

}  // namespace

GaussianMixture initialize_on_grid(const io::Volume& volume, const io::WorldFrame& frame, double threshold, int budget,
                                   InitReport* report, InitIntensity intensity) {
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
  // Cells anchored at the world origin. Such cells never merge across a
  // coordinate plane, so a foreground around the centre takes up to 8 of them
  // however large they grow: when even cells of the box's size exceed the
  // budget (budget < 8), anchor them at the box corner -aspect instead, where
  // one cell of that size holds the whole stack.
  Eigen::Vector3d corner = Eigen::Vector3d::Zero();
  auto occupied = [&](double cell) {
    std::unordered_map<std::uint64_t, int> cells;
    for (const auto& p : pos) cells[cell_key(p, corner, cell)] = 1;
    return cells.size();
  };
  // Smallest cell whose occupied count fits the budget (count falls as cells grow).
  double lo = frame.voxel_size().minCoeff() * 0.5, hi = 2.0 * frame.aspect().maxCoeff();
  if (occupied(hi) > static_cast<std::size_t>(budget)) corner = -frame.aspect();
  if (occupied(lo) <= static_cast<std::size_t>(budget)) hi = lo;
  for (int it = 0; it < 40 && hi / lo > 1.001; ++it) {
    const double mid = std::sqrt(lo * hi);
    (occupied(mid) <= static_cast<std::size_t>(budget) ? hi : lo) = mid;
  }
  const double cell = hi;
  std::unordered_map<std::uint64_t, Cell> cells;
  for (std::size_t i = 0; i < pos.size(); ++i) {
    Cell& c = cells[cell_key(pos[i], corner, cell)];
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
  const Eigen::Vector3d& voxel = frame.voxel_size();
  for (const auto& [key, c] : sorted) {
    // σ = half a grid step, but never below half a voxel along an axis.
    const Eigen::Vector3d sigma = (0.5 * voxel).cwiseMax(0.5 * cell);
    const Eigen::Vector3d centre = Eigen::Vector3d(c.px, c.py, c.pz) / c.wsum;
    const double a =
        intensity == InitIntensity::kCellMean ? c.vsum / c.count : io::sample_trilinear(volume, frame, centre);
    const GaussianParams g = isotropic_gaussian(centre, sigma, a);
    mixture.push_back(g);
  }
  if (report) {
    report->cell_world = cell;
    report->foreground = static_cast<std::int64_t>(pos.size());
  }
  return mixture;
}

GaussianMixture initialize_mixture(const io::Volume& volume, const io::WorldFrame& frame, double threshold,
                                   const GmfOptions& options, InitReport* report) {
  GaussianMixture m =
      options.init == FitInit::kMaxima
          ? initialize_at_maxima(volume, frame, threshold, options.gaussians, report)
          : initialize_on_grid(volume, frame, threshold, options.gaussians, report,
                               options.aggregation == Aggregation::kSum ? InitIntensity::kCellMean
                                                                        : InitIntensity::kAtCentre);
  // Within the fit's largest scale even if no round runs (a time budget too short
  // for one): a grid of few cells starts with σ of half a cell, and a bricked
  // fit's halo holds only Gaussians within its bound.
  const auto largest = static_cast<float>(
      std::log(options.largest_scale(frame.voxel_size().minCoeff(), frame.voxel_size().maxCoeff())));
  for (GaussianParams& g : m) {
    for (float& s : g.log_scale) s = std::min(s, largest);
  }
  return m;
}

GaussianMixture warm_start_mixture(const GaussianMixture& model, const io::WorldFrame& frame,
                                   const GmfOptions& options, const Eigen::Vector3d& origin) {
  const Eigen::Vector3d& a = frame.aspect();
  std::vector<GaussianParams> inside;
  for (GaussianParams g : model) {
    bool within = true;
    for (int i = 0; i < 3; ++i) {
      g.mean[i] = static_cast<float>(static_cast<double>(g.mean[i]) - origin[i]);
      within = within && std::abs(g.mean[i]) <= a[i];
    }
    if (within) inside.push_back(g);
  }
  const auto budget = static_cast<std::size_t>(std::max(1, options.gaussians));
  if (inside.size() > budget) {  // the brightest; ties in the model's order
    std::stable_sort(inside.begin(), inside.end(), [](const GaussianParams& l, const GaussianParams& r) {
      return l.intensity_logit > r.intensity_logit;
    });
    inside.resize(budget);
  }
  const auto largest = static_cast<float>(
      std::log(options.largest_scale(frame.voxel_size().minCoeff(), frame.voxel_size().maxCoeff())));
  GaussianMixture m;
  m.reserve(inside.size());
  for (GaussianParams g : inside) {
    for (float& s : g.log_scale) s = std::min(s, largest);
    m.push_back(g);
  }
  (void)bound_axis_ratio(flat_params(m), options.max_axis_ratio);
  return m;
}

GaussianMixture initialize_at_maxima(const io::Volume& volume, const io::WorldFrame& frame, double threshold,
                                     int budget, InitReport* report) {
  // Local maxima: foreground voxels no 26-neighbour exceeds (ties: the first in
  // index order wins, so a plateau gives one).
  struct Peak {
    float value;
    std::int64_t index;
  };
  std::vector<Peak> peaks;
  std::int64_t foreground = 0;
  const auto at = [&](int x, int y, int z) { return volume.at(x, y, z); };
  for (int z = 0; z < volume.nz; ++z)
    for (int y = 0; y < volume.ny; ++y)
      for (int x = 0; x < volume.nx; ++x) {
        const float v = at(x, y, z);
        if (!(v > threshold)) continue;
        ++foreground;
        bool peak = true;
        for (int dz = -1; dz <= 1 && peak; ++dz)
          for (int dy = -1; dy <= 1 && peak; ++dy)
            for (int dx = -1; dx <= 1 && peak; ++dx) {
              const int xn = x + dx, yn = y + dy, zn = z + dz;
              if ((dx == 0 && dy == 0 && dz == 0) || xn < 0 || yn < 0 || zn < 0 || xn >= volume.nx || yn >= volume.ny ||
                  zn >= volume.nz) {
                continue;
              }
              const float w = at(xn, yn, zn);
              const bool before = dz < 0 || (dz == 0 && (dy < 0 || (dy == 0 && dx < 0)));
              if (w > v || (w == v && before)) peak = false;
            }
        if (peak) peaks.push_back({v, (static_cast<std::int64_t>(z) * volume.ny + y) * volume.nx + x});
      }
  if (foreground == 0) {
    throw io::InputError(volume.source + ": no voxel above the foreground threshold " + std::to_string(threshold) +
                         "; lower sparse_grid.threshold");
  }
  std::sort(peaks.begin(), peaks.end(), [](const Peak& a, const Peak& b) {
    return a.value > b.value || (a.value == b.value && a.index < b.index);
  });
  if (peaks.size() > static_cast<std::size_t>(budget)) peaks.resize(static_cast<std::size_t>(budget));
  // σ: half the spacing the peaks would have if spread evenly over the foreground.
  const Eigen::Vector3d& voxel = frame.voxel_size();
  const double voxel_volume = voxel.prod();
  const double spacing =
      std::cbrt(static_cast<double>(foreground) * voxel_volume / std::max<std::size_t>(1, peaks.size()));
  const Eigen::Vector3d sigma = (0.5 * voxel).cwiseMax(Eigen::Vector3d::Constant(0.5 * spacing));
  GaussianMixture mixture;
  mixture.reserve(peaks.size());
  for (const Peak& p : peaks) {
    const int x = static_cast<int>(p.index % volume.nx);
    const int y = static_cast<int>(p.index / volume.nx % volume.ny);
    const int z = static_cast<int>(p.index / (static_cast<std::int64_t>(volume.nx) * volume.ny));
    mixture.push_back(isotropic_gaussian(frame.world_from_index(Eigen::Vector3d(x, y, z)), sigma, p.value));
  }
  if (report) {
    report->cell_world = spacing;
    report->foreground = foreground;
  }
  return mixture;
}

}  // namespace hisnegs::gmf
