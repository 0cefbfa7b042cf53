// SPDX-License-Identifier: Apache-2.0
// simulate::add_detector_noise and simulate::estimate_detector_noise: the noise added has the
// Poisson–Gaussian statistics asked for, and the estimate recovers known parameters
// (gain, read noise, background photons) within 10 % on a synthetic stack of smooth
// blobs, for a camera-like setting (offset, read noise, uint16) and for the raw-stack
// recipe (Poisson only, uint8, most of the background 0).
#include "apps/simulate/detector_noise.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <random>

#include "io/error.hpp"

namespace hisnegs::simulate {
namespace {

// A noise-free stack of counts: `blobs` Gaussian blobs (σ 4–6 voxels, peaks up to
// peak_counts) on a zero background.
io::Volume blob_stack(int blobs, double peak_counts, io::SampleType type, std::uint64_t seed) {
  io::Volume v;
  v.nx = 160, v.ny = 160, v.nz = 32;
  v.stored_as = type;
  v.source = "blobs.tif";
  v.voxels.assign(v.size(), 0.0f);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  for (int k = 0; k < blobs; ++k) {
    const double cx = 20 + 120 * u(rng), cy = 20 + 120 * u(rng), cz = 8 + 16 * u(rng);
    const double s = 4.0 + 2.0 * u(rng), a = peak_counts * (0.1 + 0.9 * u(rng));
    for (int z = 0; z < v.nz; ++z)
      for (int y = 0; y < v.ny; ++y)
        for (int x = 0; x < v.nx; ++x) {
          const double r2 = (x - cx) * (x - cx) + (y - cy) * (y - cy) + (z - cz) * (z - cz);
          v.at(x, y, z) += static_cast<float>(a * std::exp(-0.5 * r2 / (s * s)));
        }
  }
  return v;
}

TEST(DetectorNoise, AddsPoissonGaussianNoiseWithTheAskedStatistics) {
  io::Volume flat;
  flat.nx = 64, flat.ny = 64, flat.nz = 16;
  flat.stored_as = io::SampleType::kUint16;
  flat.voxels.assign(flat.size(), 0.0f);
  DetectorNoiseOptions o;
  o.background_photons = 20.0, o.gain = 2.0, o.read_noise = 3.0, o.offset = 50.0;
  const io::Volume noisy = add_detector_noise(flat, o);
  double sum = 0, sq = 0;
  for (const float v : noisy.voxels) sum += v, sq += double(v) * v;
  const double n = static_cast<double>(noisy.size()), mean = sum / n, var = sq / n - mean * mean;
  EXPECT_NEAR(mean, 50.0 + 2.0 * 20.0, 0.3);
  // gain² λ + read² + rounding's 1/12
  EXPECT_NEAR(var, 4.0 * 20.0 + 9.0 + 1.0 / 12.0, 0.05 * 89.0);
  EXPECT_EQ(add_detector_noise(flat, o).voxels, noisy.voxels) << "one seed, one stack";
}

void expect_recovered(const NoiseEstimate& est, const DetectorNoiseOptions& truth) {
  SCOPED_TRACE(est.describe());
  std::printf("estimate: %s\n", est.describe().c_str());
  EXPECT_NEAR(est.gain, truth.gain, 0.1 * truth.gain);
  if (truth.read_noise > 0.0) {
    EXPECT_NEAR(est.read_noise, truth.read_noise, 0.1 * truth.read_noise);
  } else {
    EXPECT_LT(est.read_noise, 0.1 * truth.gain) << "no read noise: the line passes through 0";
  }
  EXPECT_NEAR(est.background_photons, truth.background_photons, 0.1 * truth.background_photons);
  EXPECT_GE(est.bins, 5);
}

TEST(DetectorNoise, EstimateRecoversACamerasParameters) {
  DetectorNoiseOptions truth;
  truth.background_photons = 20.0, truth.gain = 2.0, truth.read_noise = 4.0, truth.offset = 20.0;
  truth.shot_noise = true, truth.seed = 7;
  const io::Volume noisy = add_detector_noise(blob_stack(12, 1600.0, io::SampleType::kUint16, 3), truth);
  expect_recovered(estimate_detector_noise(noisy, truth.offset), truth);
}

TEST(DetectorNoise, EstimateRecoversTheRawStackRecipe) {
  // Poisson(0.6) background and shot noise on the signal, gain 1, uint8: 55 % of the
  // background is 0, so the low bins are left out and the line rests on the blobs.
  DetectorNoiseOptions truth;
  truth.background_photons = 0.6, truth.shot_noise = true, truth.seed = 11;
  const io::Volume noisy = add_detector_noise(blob_stack(12, 200.0, io::SampleType::kUint8, 5), truth);
  expect_recovered(estimate_detector_noise(noisy, 0.0), truth);
}

TEST(DetectorNoise, EstimateRefusesWhatItCannotMeasure) {
  io::Volume flat;
  flat.nx = 40, flat.ny = 40, flat.nz = 4;
  flat.stored_as = io::SampleType::kUint8;
  flat.source = "flat.tif";
  flat.voxels.assign(flat.size(), 0.0f);
  EXPECT_THROW((void)estimate_detector_noise(flat), io::InputError);  // nothing to fit a slope to
  io::Volume tiny = flat;
  tiny.nx = 4, tiny.ny = 4;
  tiny.voxels.assign(tiny.size(), 1.0f);
  try {
    (void)estimate_detector_noise(tiny);
    FAIL() << "a 4x4 page was accepted";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("flat.tif: 4x4 pages are too small"), std::string::npos) << e.what();
  }
  io::Volume normalized = blob_stack(2, 100.0, io::SampleType::kUint8, 1);
  normalized.normalization.method = io::NormalizationMethod::kMinMax;
  EXPECT_THROW((void)estimate_detector_noise(normalized), io::InputError);
  EXPECT_THROW((void)estimate_detector_noise(blob_stack(2, 100.0, io::SampleType::kUint8, 1), -1.0), io::InputError);
}

}  // namespace
}  // namespace hisnegs::simulate
