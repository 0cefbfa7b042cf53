// SPDX-License-Identifier: Apache-2.0
// Normalization, statistics, aspect scales and trilinear sampling of io::Volume
// (CONVENTIONS "Volume" and "World space"). No file formats here.
#include "io/volume.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <limits>
#include <sstream>

#include "io/error.hpp"

namespace hisnegs::io {

std::string_view to_string(SampleType type) {
  switch (type) {
    case SampleType::kUint8:
      return "uint8";
    case SampleType::kUint16:
      return "uint16";
    case SampleType::kFloat32:
      return "float32";
  }
  return "?";
}

std::string_view to_string(SpacingSource source) {
  switch (source) {
    case SpacingSource::kDefault:
      return "default 1 um (none stored)";
    case SpacingSource::kUser:
      return "command line/config";
    case SpacingSource::kOmeXml:
      return "OME-XML PhysicalSize";
    case SpacingSource::kImageJSpacing:
      return "ImageJ spacing=";
    case SpacingSource::kImageJResolution:
      return "ImageJ X/YResolution";
    case SpacingSource::kTiffResolution:
      return "TIFF X/YResolution (cm)";
    case SpacingSource::kFile:
      return "file metadata";
    case SpacingSource::kHdf5:
      return "HDF5 metadata";
    case SpacingSource::kOmeZarr:
      return "OME-Zarr scale";
  }
  return "?";
}

std::string voxel_size_problem(double um) {
  if (std::isfinite(um) && um >= kMinVoxelUm && um <= kMaxVoxelUm) return "";
  if (!std::isfinite(um) || um <= 0) return "must be a positive finite voxel size in um";
  return "must be a voxel size in [" + number_text(kMinVoxelUm) + ", " + number_text(kMaxVoxelUm) +
         "] um (1 pm to 1 m)";
}

std::string VoxelSpacing::describe() const {
  std::ostringstream s;
  s.precision(6);
  s << um[0] << " x " << um[1] << " x " << um[2] << " um (";
  static constexpr const char* kAxis[] = {"x", "y", "z"};
  // Group axes that share a source: "x, y: ImageJ X/YResolution; z: ImageJ spacing=".
  bool first_group = true;
  for (int a = 0; a < 3; ++a) {
    bool seen_before = false;
    for (int b = 0; b < a; ++b) seen_before |= source[b] == source[a];
    if (seen_before) continue;
    if (!first_group) s << "; ";
    first_group = false;
    bool first_axis = true;
    for (int b = a; b < 3; ++b) {
      if (source[b] != source[a]) continue;
      s << (first_axis ? "" : ", ") << kAxis[b];
      first_axis = false;
    }
    s << ": " << to_string(source[a]);
  }
  s << ")";
  return s.str();
}

std::string_view to_string(NormalizationMethod method) {
  switch (method) {
    case NormalizationMethod::kNone:
      return "none";
    case NormalizationMethod::kMinMax:
      return "minmax";
    case NormalizationMethod::kPercentile:
      return "percentile";
  }
  return "?";
}

std::string Normalization::describe() const {
  std::ostringstream s;
  s.precision(9);
  s << to_string(method);
  if (method != NormalizationMethod::kNone) s << " " << raw_lo << " " << raw_hi;
  return s.str();
}

void NormalizationOptions::validate() const {
  auto bad = [](const std::string& field, double v, const std::string& rule) {
    std::ostringstream s;
    s << "volume." << field << " = " << v << ": " << rule;
    throw InputError(s.str());
  };
  if (!(percentile_lo >= 0.0 && percentile_lo < 100.0)) bad("percentile_lo", percentile_lo, "must be in [0, 100)");
  if (!(percentile_hi > percentile_lo && percentile_hi <= 100.0)) {
    bad("percentile_hi", percentile_hi, "must be in (percentile_lo, 100]");
  }
}

namespace {

struct MinMax {
  float lo = std::numeric_limits<float>::infinity();
  float hi = -std::numeric_limits<float>::infinity();
  std::size_t first_nonfinite = std::numeric_limits<std::size_t>::max();
};

// Min, max and the first NaN/Inf (if any) in one parallel pass.
MinMax parallel_min_max(const std::vector<float>& v) {
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, v.size(), 1 << 16), MinMax{},
      [&](const tbb::blocked_range<std::size_t>& r, MinMax m) {
        float lo = m.lo, hi = m.hi;
        bool finite = true;
        for (std::size_t i = r.begin(); i != r.end(); ++i) {
          lo = std::min(lo, v[i]);
          hi = std::max(hi, v[i]);
          finite &= std::isfinite(v[i]);
        }
        m.lo = lo;
        m.hi = hi;
        if (!finite) {  // rare: find the index to name it in the error
          for (std::size_t i = r.begin(); i != r.end(); ++i) {
            if (!std::isfinite(v[i])) {
              m.first_nonfinite = std::min(m.first_nonfinite, i);
              break;
            }
          }
        }
        return m;
      },
      [](MinMax a, const MinMax& b) {
        a.lo = std::min(a.lo, b.lo);
        a.hi = std::max(a.hi, b.hi);
        a.first_nonfinite = std::min(a.first_nonfinite, b.first_nonfinite);
        return a;
      });
}

void throw_nonfinite(const Volume& vol, std::size_t i) {
  const std::size_t x = i % vol.nx, y = (i / vol.nx) % vol.ny, z = i / (static_cast<std::size_t>(vol.nx) * vol.ny);
  std::ostringstream s;
  s << "voxel (x=" << x << ", y=" << y << ", z=" << z << ") is " << vol.voxels[i] << "; expected finite values";
  fail_input(vol.source, s.str());
}

// Values at percentiles ps (0..100, ascending) of v, each interpolated linearly
// between order statistics. One copy; successive nth_element calls, each on the
// part of the array above the previous one, so the whole costs O(n) per percentile.
std::vector<double> percentiles_of(std::vector<float> v, std::initializer_list<double> ps) {
  std::vector<double> out;
  if (v.empty()) return std::vector<double>(ps.size(), 0.0);
  auto first = v.begin();
  for (const double p : ps) {
    const double pos = p / 100.0 * static_cast<double>(v.size() - 1);
    const std::size_t k = static_cast<std::size_t>(std::floor(pos));
    const auto kth = v.begin() + static_cast<std::ptrdiff_t>(k);
    std::nth_element(first, kth, v.end());
    const double a = *kth;
    const double b = k + 1 < v.size() ? *std::min_element(kth + 1, v.end()) : a;
    out.push_back(a + (pos - static_cast<double>(k)) * (b - a));
    first = kth;
  }
  return out;
}

}  // namespace

void normalize(Volume& volume, const NormalizationOptions& options) {
  options.validate();
  if (volume.voxels.empty()) fail_input(volume.source, "volume is empty");
  const MinMax mm = parallel_min_max(volume.voxels);
  if (mm.first_nonfinite != std::numeric_limits<std::size_t>::max()) {
    throw_nonfinite(volume, mm.first_nonfinite);
  }
  if (!(mm.hi > mm.lo)) {
    std::ostringstream s;
    s << "volume is constant (every voxel is " << mm.lo << "); cannot normalize";
    fail_input(volume.source, s.str());
  }

  double lo = mm.lo, hi = mm.hi;
  if (options.method == NormalizationMethod::kPercentile) {
    const std::vector<double> p = percentiles_of(volume.voxels, {options.percentile_lo, options.percentile_hi});
    lo = p[0];
    hi = p[1];
    if (!(hi > lo)) {
      std::ostringstream s;
      s << "percentiles " << options.percentile_lo << " and " << options.percentile_hi << " are both " << lo
        << "; use a wider range or `minmax`";
      fail_input(volume.source, s.str());
    }
  }

  Normalization map{options.method, lo, hi, 0};
  map.clipped_voxels = apply_normalization(volume.voxels, map);
  volume.normalization = map;
}

std::int64_t apply_normalization(std::span<float> values, const Normalization& map) {
  if (map.method == NormalizationMethod::kNone) return 0;
  const double lo = map.raw_lo, hi = map.raw_hi;
  // A float stack may span more than the float range (e.g. -3e38 .. 3e38): then
  // v - lo and hi - lo overflow to inf and x would be NaN. Halving every term (a
  // power of two, exact but for denormals) keeps them finite; other data keep
  // scale 1 and bit-identical results.
  const float scale = hi - lo > std::numeric_limits<float>::max() ? 0.5f : 1.0f;
  const float flo = static_cast<float>(lo * scale);
  // Divide (not multiply by a reciprocal) so that the maximum maps to exactly 1.
  const float range = static_cast<float>((hi - lo) * scale);
  const bool clip = map.method == NormalizationMethod::kPercentile;
  return tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, values.size(), 1 << 16), std::int64_t{0},
      [&](const tbb::blocked_range<std::size_t>& r, std::int64_t n) {
        float* v = values.data();
        for (std::size_t i = r.begin(); i != r.end(); ++i) {
          float x = (v[i] * scale - flo) / range;
          if (clip) {
            n += (x < 0.0f) | (x > 1.0f);
            x = std::clamp(x, 0.0f, 1.0f);
          }
          v[i] = x;
        }
        return n;
      },
      std::plus<>());
}

VolumeStats compute_stats(const Volume& volume, double fg_rel) {
  VolumeStats st;
  if (volume.voxels.empty()) return st;
  const MinMax mm = parallel_min_max(volume.voxels);
  st.min = mm.lo;
  st.max = mm.hi;
  const double fg = st.min + fg_rel * (st.max - st.min);
  struct Acc {
    double sum = 0, sum2 = 0;
    std::size_t nonzero = 0, fg = 0;
  };
  const Acc acc = tbb::parallel_reduce(
      tbb::blocked_range<std::size_t>(0, volume.voxels.size(), 1 << 16), Acc{},
      [&](const tbb::blocked_range<std::size_t>& r, Acc a) {
        for (std::size_t i = r.begin(); i != r.end(); ++i) {
          const double x = volume.voxels[i];
          a.sum += x;
          a.sum2 += x * x;
          a.nonzero += x != st.min;
          a.fg += x > fg;
        }
        return a;
      },
      [](Acc a, const Acc& b) {
        a.sum += b.sum;
        a.sum2 += b.sum2;
        a.nonzero += b.nonzero;
        a.fg += b.fg;
        return a;
      });
  const double n = static_cast<double>(volume.voxels.size());
  st.mean = acc.sum / n;
  st.stddev = std::sqrt(std::max(0.0, acc.sum2 / n - st.mean * st.mean));
  st.nonzero_fraction = static_cast<double>(acc.nonzero) / n;
  st.foreground_fraction = static_cast<double>(acc.fg) / n;
  const std::vector<double> p = percentiles_of(volume.voxels, {1.0, 50.0, 99.0, 99.9});
  st.p01 = p[0];
  st.p50 = p[1];
  st.p99 = p[2];
  st.p999 = p[3];
  return st;
}

std::string_view to_string(AspectMode mode) { return mode == AspectMode::kPhysical ? "physical" : "shape"; }

Eigen::Vector3d aspect_scales(int nx, int ny, int nz, const VoxelSpacing& spacing, AspectMode mode) {
  Eigen::Vector3d extent(nx, ny, nz);
  if (mode == AspectMode::kPhysical) {
    extent = extent.cwiseProduct(Eigen::Vector3d(spacing.um[0], spacing.um[1], spacing.um[2]));
  }
  return extent / extent.maxCoeff();
}

WorldFrame::WorldFrame(int nx, int ny, int nz, const Eigen::Vector3d& aspect) : shape_(nx, ny, nz), aspect_(aspect) {
  const Eigen::Vector3d n = shape_.cast<double>();
  scale_ = (2.0 * aspect_.array() / n.array()).matrix();
  offset_ = (aspect_.array() * (1.0 / n.array() - 1.0)).matrix();
}

float sample_trilinear(const Volume& volume, const WorldFrame& frame, const Eigen::Vector3d& p_world) {
  if (!frame.contains(p_world)) return 0.0f;
  const Eigen::Vector3d idx = frame.index_from_world(p_world);
  const int n[3] = {volume.nx, volume.ny, volume.nz};
  int i0[3], i1[3];
  double t[3];
  for (int a = 0; a < 3; ++a) {
    const double c = std::clamp(idx[a], 0.0, static_cast<double>(n[a] - 1));
    i0[a] = static_cast<int>(std::floor(c));
    i1[a] = std::min(i0[a] + 1, n[a] - 1);
    t[a] = c - i0[a];
  }
  auto v = [&](int x, int y, int z) { return static_cast<double>(volume.at(x, y, z)); };
  const double c00 = v(i0[0], i0[1], i0[2]) * (1 - t[0]) + v(i1[0], i0[1], i0[2]) * t[0];
  const double c10 = v(i0[0], i1[1], i0[2]) * (1 - t[0]) + v(i1[0], i1[1], i0[2]) * t[0];
  const double c01 = v(i0[0], i0[1], i1[2]) * (1 - t[0]) + v(i1[0], i0[1], i1[2]) * t[0];
  const double c11 = v(i0[0], i1[1], i1[2]) * (1 - t[0]) + v(i1[0], i1[1], i1[2]) * t[0];
  const double c0 = c00 * (1 - t[1]) + c10 * t[1];
  const double c1 = c01 * (1 - t[1]) + c11 * t[1];
  return static_cast<float>(c0 * (1 - t[2]) + c1 * t[2]);
}

}  // namespace hisnegs::io
