// SPDX-License-Identifier: Apache-2.0
// add_detector_noise: one seeded stream over the voxels in order.
#include "apps/simulate/detector_noise.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <vector>

#include "io/error.hpp"

namespace hisnegs::simulate {
namespace {

void require(const char* field, double value, double lo, double hi, bool open_lo = false) {
  if (!(std::isfinite(value) && (open_lo ? value > lo : value >= lo) && value <= hi)) {
    throw io::InputError(std::string("noise.") + field + " = " + io::number_text(value) + ": must be in " +
                     (open_lo ? "(" : "[") + io::number_text(lo) + ", " + io::number_text(hi) + "]");
  }
}

}  // namespace

void DetectorNoiseOptions::validate() const {
  require("background_photons", background_photons, 0.0, 1e4);
  require("gain", gain, 0.0, 1e3, true);
  require("read_noise", read_noise, 0.0, 1e4);
  require("offset", offset, 0.0, 1e5);
}

io::Volume add_detector_noise(const io::Volume& raw, const DetectorNoiseOptions& options) {
  options.validate();
  if (raw.normalization.method != io::NormalizationMethod::kNone) {
    throw std::invalid_argument("add_detector_noise: the stack must be raw counts, not normalized");
  }
  io::Volume out = raw;
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> read(0.0, 1.0);
  const double top = raw.stored_as == io::SampleType::kUint8    ? 255.0
                     : raw.stored_as == io::SampleType::kUint16 ? 65535.0
                                                            : std::numeric_limits<double>::infinity();
  const bool integer = raw.stored_as != io::SampleType::kFloat32;
  for (float& v : out.voxels) {
    const double photons = options.background_photons + (options.shot_noise ? std::max(0.0, double(v)) / options.gain : 0.0);
    double counts = photons > 0.0 ? options.gain * static_cast<double>(std::poisson_distribution<std::int64_t>(photons)(rng))
                                  : 0.0;
    if (!options.shot_noise) counts += v;
    if (options.read_noise > 0.0) counts += options.read_noise * read(rng);
    counts += options.offset;
    if (integer) counts = std::nearbyint(counts);
    v = static_cast<float>(std::clamp(counts, 0.0, top));
  }
  return out;
}

namespace {

// One √mean bin of noise samples.
// r² on a log scale: 8 bins per octave over [2^-40, 2^40).
constexpr int kR2PerOctave = 8;
constexpr int kR2Bins = 80 * kR2PerOctave;
constexpr double kChi2MedianOver1 = 0.45493642311957283;  // median of χ²₁

struct NoiseBin {
  std::int64_t n = 0, with_zero = 0;
  double sum_mean = 0.0;  // of the window's own five voxels (unbiased for the bin's signal)
  std::vector<std::int64_t> r2_hist = std::vector<std::int64_t>(kR2Bins, 0);

  void add_r2(double r2) {
    const int i = r2 > 0.0 ? static_cast<int>(std::floor((std::log2(r2) + 40.0) * kR2PerOctave)) : 0;
    ++r2_hist[std::clamp(i, 0, kR2Bins - 1)];
  }
  // The noise variance from the median of r² (Gaussian noise: median = 0.455 σ²),
  // which the minority of windows that straddle an edge of the structure do not move;
  // interpolated log-linearly inside the histogram bin.
  [[nodiscard]] double variance() const {
    const double half = 0.5 * static_cast<double>(n);
    double below = 0.0;
    for (int i = 0; i < kR2Bins; ++i) {
      const double count = static_cast<double>(r2_hist[i]);
      if (below + count >= half && count > 0.0) {
        const double f = (half - below) / count;
        return std::exp2((i + f) / kR2PerOctave - 40.0) / kChi2MedianOver1;
      }
      below += count;
    }
    return 0.0;
  }
  [[nodiscard]] double signal() const { return sum_mean / static_cast<double>(n); }
};

constexpr int kNoiseBins = 64;
constexpr std::int64_t kMinBinSamples = 100;
constexpr double kMaxZeroFraction = 0.01;

// Noise samples of the windows along one axis: voxel stride `step` along the window,
// `side` to the rows beside it; `len`/`side_len` their extents (windows need 2 voxels
// either side, the mean rows 1 voxel either side).
void accumulate_axis(const io::Volume& raw, std::size_t step, std::size_t side, int len, int side_len, double top,
                     double sqrt_hi, std::vector<NoiseBin>& bins) {
  static constexpr std::array<double, 5> kW{1.0, -4.0, 6.0, -4.0, 1.0};
  const double norm = 1.0 / std::sqrt(70.0);
  const float* v = raw.voxels.data();
  for (std::size_t base = 0; base < raw.size(); ++base) {
    const int x = static_cast<int>(base % raw.nx);
    const int y = static_cast<int>((base / raw.nx) % raw.ny);
    const int along = step == 1 ? x : y;
    const int beside = step == 1 ? y : x;
    if (along < 2 || along + 2 >= len || beside < 1 || beside + 1 >= side_len) continue;
    double r = 0.0, mean = 0.0, own = 0.0;
    bool clipped = false, zero = false;
    for (int t = -2; t <= 2; ++t) {
      const std::size_t i = base + static_cast<std::ptrdiff_t>(t) * static_cast<std::ptrdiff_t>(step);
      const double c = v[i], lo = v[i - side], hi = v[i + side];
      r += kW[t + 2] * c;
      own += c;
      mean += lo + hi;
      clipped |= c >= top || lo >= top || hi >= top;
      zero |= c <= 0.0 || lo <= 0.0 || hi <= 0.0;
    }
    if (clipped) continue;
    mean /= 10.0;
    const int b = std::min(kNoiseBins - 1, static_cast<int>(std::sqrt(std::max(0.0, mean)) / sqrt_hi * kNoiseBins));
    NoiseBin& bin = bins[b];
    ++bin.n;
    bin.with_zero += zero ? 1 : 0;
    bin.sum_mean += own / 5.0;
    r *= norm;
    bin.add_r2(r * r);
  }
}

// The mean of each voxel's 3×3×3 box (edges clamped), separably.
std::vector<float> box_mean_3(const io::Volume& v) {
  std::vector<float> a = v.voxels, b(v.size());
  const std::array<std::size_t, 3> stride{1, static_cast<std::size_t>(v.nx), static_cast<std::size_t>(v.nx) * v.ny};
  const std::array<int, 3> extent{v.nx, v.ny, v.nz};
  for (int axis = 0; axis < 3; ++axis) {
    for (std::size_t i = 0; i < v.size(); ++i) {
      const int c = static_cast<int>((i / stride[axis]) % static_cast<std::size_t>(extent[axis]));
      const std::size_t lo = c > 0 ? i - stride[axis] : i, hi = c + 1 < extent[axis] ? i + stride[axis] : i;
      b[i] = (a[lo] + a[i] + a[hi]) / 3.0f;
    }
    std::swap(a, b);
  }
  return a;
}

struct LineFit {
  double a = 0.0, b = 0.0;
};

// Weighted least squares of var = a · mean + b, weights n / var_w².
LineFit fit_line(const std::vector<NoiseBin>& bins, const LineFit* weights_from) {
  double sw = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (const NoiseBin& bin : bins) {
    const double x = bin.signal(), y = bin.variance();
    const double var = weights_from ? std::max(1e-12, weights_from->a * x + weights_from->b) : std::max(1e-12, y);
    const double w = static_cast<double>(bin.n) / (var * var);
    sw += w;
    sx += w * x;
    sy += w * y;
    sxx += w * x * x;
    sxy += w * x * y;
  }
  const double det = sw * sxx - sx * sx;
  LineFit fit;
  fit.a = (sw * sxy - sx * sy) / det;
  fit.b = (sy - fit.a * sx) / sw;
  return fit;
}

}  // namespace

std::string NoiseEstimate::describe() const {
  char buf[400];
  std::snprintf(buf, sizeof buf,
                "gain %.4g counts/photon, read noise %.4g counts (offset %.4g given), background %.4g photons/voxel "
                "(mean %.4g counts); line var = %.4g mean %+.4g fitted to %d bins, %lld samples, local means %.4g-%.4g "
                "counts, rms %.1f %%",
                gain, read_noise, offset, background_photons, background_mean, gain, variance_at_zero, bins,
                static_cast<long long>(samples), mean_lo, mean_hi, 100.0 * fit_rms);
  return buf;
}

NoiseEstimate estimate_detector_noise(const io::Volume& raw, double offset) {
  if (raw.normalization.method != io::NormalizationMethod::kNone) {
    throw io::InputError(raw.source + ": the noise estimate needs the stack's raw counts, not normalized values");
  }
  if (!(std::isfinite(offset) && offset >= 0.0)) {
    throw io::InputError(raw.source + ": noise offset = " + io::number_text(offset) + ": must be >= 0");
  }
  const bool along_x = raw.nx >= 5 && raw.ny >= 3, along_y = raw.ny >= 5 && raw.nx >= 3;
  if (!along_x && !along_y) {
    throw io::InputError(raw.source + ": " + std::to_string(raw.nx) + "x" + std::to_string(raw.ny) +
                     " pages are too small for a noise estimate (5 voxels along x or y needed)");
  }
  const double top = raw.stored_as == io::SampleType::kUint8    ? 255.0
                     : raw.stored_as == io::SampleType::kUint16 ? 65535.0
                                                            : std::numeric_limits<double>::infinity();
  const double hi = std::max(1.0, static_cast<double>(*std::max_element(raw.voxels.begin(), raw.voxels.end())));
  std::vector<NoiseBin> all(kNoiseBins);
  const std::size_t row = static_cast<std::size_t>(raw.nx);
  if (along_x) accumulate_axis(raw, 1, row, raw.nx, raw.ny, top, std::sqrt(hi), all);
  if (along_y) accumulate_axis(raw, row, 1, raw.ny, raw.nx, top, std::sqrt(hi), all);

  std::vector<NoiseBin> used;
  NoiseEstimate est;
  est.offset = offset;
  for (const NoiseBin& bin : all) {
    if (bin.n < kMinBinSamples || bin.with_zero > kMaxZeroFraction * static_cast<double>(bin.n)) continue;
    used.push_back(bin);
    est.samples += bin.n;
  }
  if (used.size() < 2) {
    throw io::InputError(raw.source + ": too little signal range for a noise estimate (" + std::to_string(used.size()) +
                     " usable intensity bins; 2 needed)");
  }
  const LineFit first = fit_line(used, nullptr);
  const LineFit line = fit_line(used, &first);
  if (!(line.a > 0.0)) {
    throw io::InputError(raw.source + ": the noise variance does not grow with the signal (slope " + io::number_text(line.a) +
                     " over " + std::to_string(used.size()) +
                     " intensity bins): too little smooth signal to measure a gain");
  }
  est.gain = line.a;
  est.variance_at_zero = line.b;
  est.read_noise = std::sqrt(std::max(0.0, line.b + line.a * offset));
  est.bins = static_cast<int>(used.size());
  est.mean_lo = used.front().signal();
  est.mean_hi = used.back().signal();
  double sq = 0.0;
  for (const NoiseBin& bin : used) {
    const double predicted = line.a * bin.signal() + line.b;
    const double rel = (bin.variance() - predicted) / std::max(1e-12, predicted);
    sq += rel * rel;
  }
  est.fit_rms = std::sqrt(sq / static_cast<double>(used.size()));

  // The background: the stack's typical value (its median; most of a neuron stack is
  // background), then the mean of the voxels whose 3×3×3 box mean is within 3 of the
  // box mean's noise standard deviations above the current estimate (which leaves the
  // neuron and most of its dim halo out), three times. The noise's variance is floored
  // at gain² (one photon's) so that a stack whose median is 0 still gets a cut above
  // its Poisson zeros.
  const std::vector<float> box = box_mean_3(raw);
  std::vector<float> values = raw.voxels;
  auto mid = values.begin() + static_cast<std::ptrdiff_t>(values.size() / 2);
  std::nth_element(values.begin(), mid, values.end());
  double mean = *mid;
  for (int pass = 0; pass < 3; ++pass) {
    const double var = std::max(line.a * std::max(mean, line.a) + line.b, line.a * line.a);
    const double cut = mean + 3.0 * std::sqrt(std::max(0.0, var) / 27.0);
    double sum = 0.0;
    std::int64_t n = 0;
    for (std::size_t i = 0; i < raw.size(); ++i) {
      if (box[i] > cut) continue;
      sum += raw.voxels[i];
      ++n;
    }
    if (n > 0) mean = sum / static_cast<double>(n);
  }
  est.background_mean = mean;
  est.background_photons = est.gain > 0.0 ? (est.background_mean - offset) / est.gain : 0.0;
  return est;
}

}  // namespace hisnegs::simulate
