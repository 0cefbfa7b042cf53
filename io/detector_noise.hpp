// SPDX-License-Identifier: Apache-2.0
// Raw-like test data: the detector noise of a fluorescence microscope (Poisson shot
// noise of the photons, Gaussian read noise, a camera offset, quantized and clipped
// to the stack's sample type) added to a stack of counts, as `hisnegs noise` does to
// the shared, background-subtracted volumes. Knows no file format.
#pragma once

#include <cstdint>

#include "io/volume.hpp"

namespace hisnegs::io {

// counts' = clip(round(offset + gain · Poisson(photons) + Normal(0, read_noise²))),
// photons = background_photons (+ counts / gain with shot_noise): the Poisson–Gaussian
// model of fluorescence detectors (e.g. Foi et al. 2008, "Practical Poissonian-
// Gaussian noise modeling"). The defaults are issue 33's recipe for op1: Poisson
// noise of mean 0.6 counts added to its uint8 voxels (55 % of the background stays
// 0, mean 0.0024 and p99 0.0118 after min-max normalization, like a raw confocal
// stack of the same family).
struct DetectorNoiseOptions {
  double background_photons = 0.6;  // expected autofluorescence/dark photons per voxel, [0, 1e4]
  double gain = 1.0;                // counts per photon, (0, 1e3]
  double read_noise = 0.0;          // std dev of the read noise, counts, [0, 1e4]
  double offset = 0.0;              // camera bias, counts, [0, 1e5]
  // Also resample the stack's own values as photons (counts / gain): for a clean
  // (noise-free) stack; the shared stacks are real images that carry their own shot
  // noise already. false: the stack's values are kept and the background's noise added.
  bool shot_noise = false;
  std::uint64_t seed = 1;
  void validate() const;  // throws InputError("noise.FIELD = VALUE: rule")
};

// `raw` (counts as read, not normalized; stored_as decides the rounding and the
// clipping: uint8 0..255, uint16 0..65535, float32 >= 0 unrounded) with detector noise
// added. Deterministic for a seed (one stream, voxel order), spacing and type kept.
[[nodiscard]] Volume add_detector_noise(const Volume& raw, const DetectorNoiseOptions& options);

}  // namespace hisnegs::io
