// SPDX-License-Identifier: Apache-2.0
// FloorTable, the per-pixel chord length and floor, and the calibration of the
// samples a ray gathers per voxel against the ground-truth ray marcher.
#include "splat/background_floor.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <random>

#include "splat/raymarch.hpp"

namespace hisnegs::splat {
namespace {

constexpr int kPerOctave = 16;  // table points per doubling of n
constexpr int kOctaves = 26;    // n up to 2^26: far more samples than any ray through a stack

// The distribution of trilinear samples of `noise` at uniformly random interior
// points, as at most max(atoms, 64) equal-width bins (each atom its bin's mean).
gmf::BackgroundModel interpolated_distribution(const io::Volume& noise, std::mt19937_64& rng, int atoms) {
  constexpr int kSamples = 1 << 19;
  const int bins = std::clamp(atoms, 64, 4096);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<double> values(kSamples);
  double top = 0.0;
  for (double& v : values) {
    const double x = u(rng) * (noise.nx - 1), y = u(rng) * (noise.ny - 1), z = u(rng) * (noise.nz - 1);
    const int x0 = std::min(static_cast<int>(x), noise.nx - 2), y0 = std::min(static_cast<int>(y), noise.ny - 2),
              z0 = std::min(static_cast<int>(z), noise.nz - 2);
    const double fx = x - x0, fy = y - y0, fz = z - z0;
    v = 0.0;
    for (int c = 0; c < 8; ++c) {
      const int dx = c & 1, dy = (c >> 1) & 1, dz = c >> 2;
      v += (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy) * (dz ? fz : 1 - fz) * noise.at(x0 + dx, y0 + dy, z0 + dz);
    }
    top = std::max(top, v);
  }
  gmf::BackgroundModel m;
  m.voxels = kSamples;
  if (!(top > 0.0)) {
    m.values = {0.0};
    m.cdf = {1.0};
    return m;
  }
  std::vector<double> sum(static_cast<std::size_t>(bins), 0.0);
  std::vector<std::int64_t> count(static_cast<std::size_t>(bins), 0);
  for (const double v : values) {
    const auto b = static_cast<std::size_t>(std::min(bins - 1, static_cast<int>(v / top * bins)));
    sum[b] += v;
    ++count[b];
  }
  std::int64_t running = 0;
  for (std::size_t b = 0; b < sum.size(); ++b) {
    if (count[b] == 0) continue;
    running += count[b];
    m.values.push_back(sum[b] / static_cast<double>(count[b]));
    m.cdf.push_back(static_cast<double>(running) / kSamples);
  }
  m.cdf.back() = 1.0;
  return m;
}

}  // namespace

FloorTable::FloorTable(const gmf::BackgroundModel& model) : samples_per_voxel_(model.samples_per_voxel) {
  if (model.none()) return;
  values_.resize(kPerOctave * kOctaves + 1);
  for (std::size_t i = 0; i < values_.size(); ++i) {
    values_[i] = model.expected_max(std::exp2(static_cast<double>(i) / kPerOctave));
  }
}

int FloorTable::points_per_octave() { return kPerOctave; }

double FloorTable::at_voxels(double voxels) const {
  if (values_.empty() || !(voxels > 0.0)) return 0.0;
  const double n = samples_per_voxel_ * voxels;
  if (n <= 1.0) return values_.front();
  const double x = std::log2(n) * kPerOctave;
  const auto i = static_cast<std::size_t>(x);
  if (i + 1 >= values_.size()) return values_.back();
  const double f = x - static_cast<double>(i);
  return values_[i] + f * (values_[i + 1] - values_[i]);
}

double box_path_voxels(const io::WorldFrame& frame, const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) {
  double t_in = 0, t_out = 0;
  if (!ray_box_segment(frame, origin, dir, t_in, t_out)) return 0.0;
  // World -> index scale per axis is 1 / voxel size.
  const Eigen::Vector3d chord = (t_out - t_in) * dir;
  return chord.cwiseQuotient(frame.voxel_size()).norm();
}

std::vector<float> background_floor(const FloorTable& table, const io::WorldFrame& frame, const Intrinsics& K,
                                    const CameraView& view) {
  std::vector<float> floor(static_cast<std::size_t>(K.width) * K.height, 0.0f);
  if (table.none()) return floor;
  const Eigen::Vector3d origin = view.center_world();
  tbb::parallel_for(tbb::blocked_range<int>(0, K.height), [&](const auto& rows) {
    for (int r = rows.begin(); r != rows.end(); ++r) {
      for (int c = 0; c < K.width; ++c) {
        const Eigen::Vector3d dir = ray_direction(K, view, c + 0.5, r + 0.5);
        floor[static_cast<std::size_t>(r) * K.width + c] =
            static_cast<float>(table.at_voxels(box_path_voxels(frame, origin, dir)));
      }
    }
  });
  return floor;
}

namespace {

// P(X <= v) of `model` (0 below its first atom).
double cdf_at(const gmf::BackgroundModel& model, double v) {
  const auto it = std::upper_bound(model.values.begin(), model.values.end(), v);
  return it == model.values.begin() ? 0.0 : model.cdf[static_cast<std::size_t>(it - model.values.begin() - 1)];
}

}  // namespace

RegionFloor::RegionFloor(const gmf::BackgroundField& field, const io::WorldFrame& frame)
    : regions_(field.regions), frame_(frame) {
  if (field.none()) return;
  double top = 0.0;
  for (int r = 0; r < regions_.count(); ++r) {
    const gmf::BackgroundModel& m = field.at(r);
    if (!m.none()) {
      top = std::max(top, m.values.back());
      samples_per_voxel_ = m.samples_per_voxel;
    }
  }
  levels_.resize(kLevels);
  std::vector<double> edges(kLevels);
  for (int i = 0; i < kLevels; ++i) {
    edges[static_cast<std::size_t>(i)] = top * i / (kLevels - 1);
    levels_[static_cast<std::size_t>(i)] = i == 0 ? 0.0 : top * (i - 0.5) / (kLevels - 1);
  }
  edges.back() = top;  // every atom at or below the last edge: F = 1 there
  log_cdf_.resize(static_cast<std::size_t>(regions_.count()) * kLevels);
  for (int r = 0; r < regions_.count(); ++r) {
    const gmf::BackgroundModel& m = field.at(r);
    for (int i = 0; i < kLevels; ++i) {
      const double F = m.none() ? 1.0 : cdf_at(m, edges[static_cast<std::size_t>(i)]);
      log_cdf_[static_cast<std::size_t>(r) * kLevels + i] = F > 0.0 ? static_cast<float>(std::log(F)) : -1e30f;
    }
  }
}

double RegionFloor::at(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir) const {
  double t_in = 0, t_out = 0;
  if (none() || !ray_box_segment(frame_, origin, dir, t_in, t_out)) return 0.0;
  // Continuous index coordinates with the box at [0, N]: region edges are integers.
  const Eigen::Vector3d u0 = frame_.index_from_world(origin + t_in * dir).array() + 0.5;
  const Eigen::Vector3d u1 = frame_.index_from_world(origin + t_out * dir).array() + 0.5;
  const double length = (u1 - u0).norm();
  // At most kMaxPerAxis - 1 edges per axis are crossed, so the chord has at most
  // 3 (kMaxPerAxis - 1) + 1 pieces: fixed arrays, no allocation per pixel.
  constexpr int kMaxCuts = 3 * (gmf::BackgroundRegions::kMaxPerAxis - 1) + 2;
  std::array<double, kMaxCuts> cuts{};
  int n_cuts = 0;
  cuts[n_cuts++] = 0.0;
  cuts[n_cuts++] = 1.0;
  for (int a = 0; a < 3; ++a) {
    for (int k = 1; k < regions_.cells[a]; ++k) {
      const double e = regions_.edge(a, k);
      if ((u0[a] - e) * (u1[a] - e) < 0.0) cuts[static_cast<std::size_t>(n_cuts++)] = (e - u0[a]) / (u1[a] - u0[a]);
    }
  }
  std::sort(cuts.begin(), cuts.begin() + n_cuts);
  std::array<std::pair<int, double>, kMaxCuts> samples{};  // (region, c L_j)
  int n_samples = 0;
  double total = 0.0;
  for (int i = 0; i + 1 < n_cuts; ++i) {
    const double n = samples_per_voxel_ * (cuts[i + 1] - cuts[i]) * length;
    if (!(n > 0.0)) continue;
    const Eigen::Vector3d mid = u0 + 0.5 * (cuts[i] + cuts[i + 1]) * (u1 - u0);
    int cell[3];
    for (int a = 0; a < 3; ++a) {
      cell[a] = regions_.cell_of(a, std::clamp(static_cast<int>(std::floor(mid[a])), 0, regions_.shape[a] - 1));
    }
    samples[static_cast<std::size_t>(n_samples++)] = {
        cell[0] + regions_.cells[0] * (cell[1] + regions_.cells[1] * cell[2]), n};
    total += n;
  }
  if (!(total > 0.0)) return 0.0;
  const double scale = total < 1.0 ? 1.0 / total : 1.0;  // at least one sample, as E[max of n < 1] is E[max of 1]
  // E[max] = Σ_i m_i (P_i − P_(i−1)) = m_top − Σ_(i < top) (m_(i+1) − m_i) P_i, P_i = Π_j F_j(v_i)^(n_j),
  // summed from the top down until P_i is negligible.
  double mean = levels_.back();
  for (int i = kLevels - 2; i >= 0; --i) {
    double log_p = 0.0;
    for (int k = 0; k < n_samples; ++k) {
      const auto& [region, n] = samples[static_cast<std::size_t>(k)];
      log_p += scale * n * log_cdf_[static_cast<std::size_t>(region) * kLevels + i];
    }
    if (log_p < -40.0) break;
    mean -= (levels_[static_cast<std::size_t>(i) + 1] - levels_[static_cast<std::size_t>(i)]) * std::exp(log_p);
  }
  return mean;
}

BackgroundFloors::BackgroundFloors(const gmf::BackgroundModel& model, const io::WorldFrame& frame)
    : table_(model), frame_(frame) {}

BackgroundFloors::BackgroundFloors(const gmf::BackgroundField& field, const io::WorldFrame& frame) : frame_(frame) {
  if (field.regional()) {
    regional_ = RegionFloor(field, frame);
  } else {
    table_ = FloorTable(field.merged);
  }
}

std::vector<float> BackgroundFloors::operator()(const Intrinsics& K, const CameraView& view) const {
  if (none()) return {};
  if (!regional()) return background_floor(table_, frame_, K, view);
  std::vector<float> floor(static_cast<std::size_t>(K.width) * K.height, 0.0f);
  const Eigen::Vector3d origin = view.center_world();
  tbb::parallel_for(tbb::blocked_range<int>(0, K.height), [&](const auto& rows) {
    for (int r = rows.begin(); r != rows.end(); ++r) {
      for (int c = 0; c < K.width; ++c) {
        floor[static_cast<std::size_t>(r) * K.width + c] =
            static_cast<float>(regional_.at(origin, ray_direction(K, view, c + 0.5, r + 0.5)));
      }
    }
  });
  return floor;
}

BackgroundFloors floors_of(const gmf::CheckpointMeta& meta, const std::string& source, bool draw) {
  if (!draw) return {};
  const gmf::BackgroundField field = gmf::background_field_of(meta, source);
  const std::optional<io::WorldFrame> frame = gmf::model_frame(meta);
  if (field.none() || !frame) return {};
  return BackgroundFloors(field, *frame);
}

namespace {

// A noise-only block drawn from `model` with the stack's voxel size, at most 64
// voxels a side.
io::Volume noise_block(const gmf::BackgroundModel& model, const io::WorldFrame& frame, std::mt19937_64& rng) {
  io::Volume noise;
  const Eigen::Vector3i& shape = frame.shape();
  noise.nx = std::min(shape.x(), 64);
  noise.ny = std::min(shape.y(), 64);
  noise.nz = std::min(shape.z(), 64);
  noise.voxels.resize(noise.size());
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (float& v : noise.voxels) v = static_cast<float>(model.quantile(u(rng)));
  return noise;
}

// Rays of one chord-length bin, a factor 1.25 wide, and their mean MIP.
struct ChordBin {
  std::vector<double> chords;
  double mean_mip = 0;
};

// (chord, MIP) pairs of 24 orbit views of 64 x 64 pixels of the block (chords of
// under 4 voxels left out: too few samples to say anything), binned by chord
// length; bins of fewer than 40 rays are left out. `rays` counts the pairs.
std::vector<ChordBin> chord_bins(const RayMarcher& marcher, const io::WorldFrame& box,
                                 const Eigen::Vector3d& unit_aspect, int& rays) {
  CameraOptions camera;
  camera.width = camera.height = 64;
  camera.fov_deg = 40.0;
  camera.orbit_radius = 1.2 * unit_aspect.norm() / std::tan(0.5 * camera.fov_deg * 3.14159265358979 / 180.0);
  camera.far = 4.0 * camera.orbit_radius;
  const CameraSet cameras = custom_orbit(camera, {-60.0, -20.0, 20.0, 60.0}, even_azimuths(6, 7.0));
  std::vector<double> chord, mip;
  std::vector<float> image(static_cast<std::size_t>(camera.width) * camera.height);
  for (const CameraView& view : cameras.views) {
    marcher.render(cameras.intrinsics, view, image);
    const Eigen::Vector3d origin = view.center_world();
    for (int r = 0; r < camera.height; ++r) {
      for (int c = 0; c < camera.width; ++c) {
        const double L = box_path_voxels(box, origin, ray_direction(cameras.intrinsics, view, c + 0.5, r + 0.5));
        if (L < 4.0) continue;
        chord.push_back(L);
        mip.push_back(image[static_cast<std::size_t>(r) * camera.width + c]);
      }
    }
  }
  rays = static_cast<int>(chord.size());
  std::vector<std::vector<std::size_t>> members(64);
  for (std::size_t i = 0; i < chord.size(); ++i) {
    members[std::min<std::size_t>(63, static_cast<std::size_t>(std::log(chord[i] / 4.0) / std::log(1.25)))].push_back(
        i);
  }
  std::vector<ChordBin> bins;
  for (const auto& m : members) {
    if (m.size() < 40) continue;
    ChordBin b;
    for (const std::size_t i : m) {
      b.chords.push_back(chord[i]);
      b.mean_mip += mip[i];
    }
    b.mean_mip /= static_cast<double>(m.size());
    bins.push_back(std::move(b));
  }
  return bins;
}

// The samples per voxel c whose E[max of c L samples] best matches the bins' mean
// MIP (relative squared error; golden-section search over ln c in [ln 0.02, ln 8],
// E[max] rises with c), and the worst relative error there.
double fit_samples_per_voxel(const gmf::BackgroundModel& model, const std::vector<ChordBin>& bins, double& worst) {
  const auto error = [&](double c, double* largest) {
    double sum = 0.0;
    if (largest) *largest = 0.0;
    for (const ChordBin& b : bins) {
      double predicted = 0.0;
      for (const double L : b.chords) predicted += model.expected_max(c * L);
      predicted /= static_cast<double>(b.chords.size());
      const double rel = b.mean_mip > 0 ? (predicted - b.mean_mip) / b.mean_mip : predicted;
      sum += rel * rel;
      if (largest) *largest = std::max(*largest, std::abs(rel));
    }
    return sum;
  };
  double lo = std::log(0.02), hi = std::log(8.0);
  const double phi = 0.5 * (std::sqrt(5.0) - 1.0);
  double x1 = hi - phi * (hi - lo), x2 = lo + phi * (hi - lo);
  double f1 = error(std::exp(x1), nullptr), f2 = error(std::exp(x2), nullptr);
  for (int it = 0; it < 60; ++it) {
    if (f1 < f2) {
      hi = x2;
      x2 = x1;
      f2 = f1;
      x1 = hi - phi * (hi - lo);
      f1 = error(std::exp(x1), nullptr);
    } else {
      lo = x1;
      x1 = x2;
      f1 = f2;
      x2 = lo + phi * (hi - lo);
      f2 = error(std::exp(x2), nullptr);
    }
  }
  const double c = std::exp(0.5 * (lo + hi));
  (void)error(c, &worst);
  return c;
}

}  // namespace

FloorCalibration calibrate_background(gmf::BackgroundModel& model, const io::WorldFrame& frame,
                                      const RaymarchOptions& options, std::uint64_t seed) {
  FloorCalibration out;
  out.samples_per_voxel = model.samples_per_voxel;
  if (model.none()) return out;
  std::mt19937_64 rng(seed);
  const io::Volume noise = noise_block(model, frame, rng);
  const Eigen::Vector3d aspect = 0.5 * frame.voxel_size().cwiseProduct(Eigen::Vector3d(noise.nx, noise.ny, noise.nz));
  const Eigen::Vector3d unit_aspect = aspect / aspect.maxCoeff();  // the marcher's world: max half-extent 1
  const io::WorldFrame box(noise.nx, noise.ny, noise.nz, unit_aspect);
  const RayMarcher marcher(noise, box, options);
  // What a ray samples is the trilinear interpolation of the voxels, not a voxel:
  // its distribution (at uniformly random points) has the lighter tail the MIP
  // sees. The model becomes that distribution.
  model = interpolated_distribution(noise, rng, static_cast<int>(model.values.size()));
  const std::vector<ChordBin> bins = chord_bins(marcher, box, unit_aspect, out.rays);
  if (bins.empty()) return out;
  out.samples_per_voxel = fit_samples_per_voxel(model, bins, out.worst_relative_error);
  model.samples_per_voxel = out.samples_per_voxel;
  return out;
}

FloorCalibration calibrate_background(gmf::BackgroundField& field, const io::WorldFrame& frame,
                                      const RaymarchOptions& options, std::uint64_t seed) {
  gmf::BackgroundModel* basis = &field.merged;
  if (field.merged.none()) {
    for (gmf::BackgroundModel& m : field.models) {
      if (!m.none() && (basis->none() || m.voxels > basis->voxels)) basis = &m;
    }
  }
  const gmf::BackgroundModel before = *basis;
  const FloorCalibration out = calibrate_background(*basis, frame, options, seed);
  std::mt19937_64 rng(seed + 1);
  for (gmf::BackgroundModel& m : field.models) {
    if (&m == basis || m.none()) continue;
    if (m == before) {
      m = *basis;  // a region that took the merged model
      continue;
    }
    const io::Volume noise = noise_block(m, frame, rng);
    const std::int64_t voxels = m.voxels;
    m = interpolated_distribution(noise, rng, static_cast<int>(m.values.size()));
    m.voxels = voxels;
    m.samples_per_voxel = out.samples_per_voxel;
  }
  return out;
}

}  // namespace hisnegs::splat
