// SPDX-License-Identifier: Apache-2.0
// FloorTable, the per-pixel chord length and floor, and the calibration of the
// samples a ray gathers per voxel against the ground-truth ray marcher.
#include "splat/background_floor.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <random>

#include "splat/raymarch.hpp"

namespace hisnegs::splat {
namespace {

constexpr int kPerOctave = 16;  // table points per doubling of n
constexpr int kOctaves = 26;    // n up to 2^26: far more samples than any ray through a stack

// The distribution of trilinear samples of `noise` at uniformly random interior
// points, as at most max(atoms, 64) equal-width bins (each atom its bin's mean).
io::BackgroundModel interpolated_distribution(const io::Volume& noise, std::mt19937_64& rng, int atoms) {
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
  io::BackgroundModel m;
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

FloorTable::FloorTable(const io::BackgroundModel& model) : samples_per_voxel_(model.samples_per_voxel) {
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

BackgroundFloors::BackgroundFloors(const io::BackgroundModel& model, const io::WorldFrame& frame)
    : table_(model), frame_(frame) {}

std::vector<float> BackgroundFloors::operator()(const Intrinsics& K, const CameraView& view) const {
  if (none()) return {};
  return background_floor(table_, frame_, K, view);
}

BackgroundFloors floors_of(const gmf::CheckpointMeta& meta, const std::string& source, bool draw) {
  if (!draw) return {};
  const io::BackgroundModel model = gmf::background_of(meta, source);
  const std::optional<io::WorldFrame> frame = gmf::model_frame(meta);
  if (model.none() || !frame) return {};
  return BackgroundFloors(model, *frame);
}

namespace {

// A noise-only block drawn from `model` with the stack's voxel size, at most 64
// voxels a side.
io::Volume noise_block(const io::BackgroundModel& model, const io::WorldFrame& frame, std::mt19937_64& rng) {
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
std::vector<ChordBin> chord_bins(const RayMarcher& marcher, const io::WorldFrame& box, const Eigen::Vector3d& unit_aspect,
                                 int& rays) {
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
    members[std::min<std::size_t>(63, static_cast<std::size_t>(std::log(chord[i] / 4.0) / std::log(1.25)))].push_back(i);
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
double fit_samples_per_voxel(const io::BackgroundModel& model, const std::vector<ChordBin>& bins, double& worst) {
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

FloorCalibration calibrate_background(io::BackgroundModel& model, const io::WorldFrame& frame,
                                      const RaymarchOptions& options, std::uint64_t seed) {
  FloorCalibration out;
  out.samples_per_voxel = model.samples_per_voxel;
  if (model.none()) return out;
  std::mt19937_64 rng(seed);
  const io::Volume noise = noise_block(model, frame, rng);
  const Eigen::Vector3d aspect =
      0.5 * frame.voxel_size().cwiseProduct(Eigen::Vector3d(noise.nx, noise.ny, noise.nz));
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

}  // namespace hisnegs::splat
