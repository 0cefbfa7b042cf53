// SPDX-License-Identifier: Apache-2.0
// add_detector_noise: one seeded stream over the voxels in order.
#include "io/detector_noise.hpp"

#include <algorithm>
#include <cmath>
#include <random>

#include "io/error.hpp"

namespace hisnegs::io {
namespace {

void require(const char* field, double value, double lo, double hi, bool open_lo = false) {
  if (!(std::isfinite(value) && (open_lo ? value > lo : value >= lo) && value <= hi)) {
    throw InputError(std::string("noise.") + field + " = " + number_text(value) + ": must be in " +
                     (open_lo ? "(" : "[") + number_text(lo) + ", " + number_text(hi) + "]");
  }
}

}  // namespace

void DetectorNoiseOptions::validate() const {
  require("background_photons", background_photons, 0.0, 1e4);
  require("gain", gain, 0.0, 1e3, true);
  require("read_noise", read_noise, 0.0, 1e4);
  require("offset", offset, 0.0, 1e5);
}

Volume add_detector_noise(const Volume& raw, const DetectorNoiseOptions& options) {
  options.validate();
  if (raw.normalization.method != NormalizationMethod::kNone) {
    throw std::invalid_argument("add_detector_noise: the stack must be raw counts, not normalized");
  }
  Volume out = raw;
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> read(0.0, 1.0);
  const double top = raw.stored_as == SampleType::kUint8    ? 255.0
                     : raw.stored_as == SampleType::kUint16 ? 65535.0
                                                            : std::numeric_limits<double>::infinity();
  const bool integer = raw.stored_as != SampleType::kFloat32;
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

}  // namespace hisnegs::io
