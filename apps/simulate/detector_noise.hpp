// SPDX-License-Identifier: Apache-2.0
// Raw-like test data: the detector noise of a fluorescence microscope (Poisson shot
// noise of the photons, Gaussian read noise, a camera offset, quantized and clipped
// to the stack's sample type) added to a stack of counts, as `hisnegs noise` does to
// the shared, background-subtracted volumes. Knows no file format.
#pragma once

#include <cstdint>

#include "io/volume.hpp"

namespace hisnegs::simulate {

// counts' = clip(round(offset + gain · Poisson(photons) + Normal(0, read_noise²))),
// photons = background_photons (+ counts / gain with shot_noise): the Poisson–Gaussian
// model of fluorescence detectors (e.g. Foi et al. 2008, "Practical Poissonian-
// Gaussian noise modeling"). The defaults are the noisy-op1 recipe of docs/benchmarks.md: Poisson
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
  void validate() const;  // throws io::InputError("noise.FIELD = VALUE: rule")
};

// `raw` (counts as read, not normalized; stored_as decides the rounding and the
// clipping: uint8 0..255, uint16 0..65535, float32 >= 0 unrounded) with detector noise
// added. Deterministic for a seed (one stream, voxel order), spacing and type kept.
[[nodiscard]] io::Volume add_detector_noise(const io::Volume& raw, const DetectorNoiseOptions& options);

// The Poisson–Gaussian parameters of a raw stack (counts, not normalized), measured
// the way Foi et al. (2008) do: the noise variance is affine in the signal,
// var = a · mean + b, with a = gain and b = read_noise² − gain · offset. Each voxel
// with two voxels either side along x (and along y) gives one noise sample: the
// fourth difference (1, −4, 6, −4, 1)/√70 of its five voxels, which leaves the
// signal's polynomials up to degree 3 out and keeps the noise's variance. Samples are
// binned by a local mean from the ten voxels of the rows beside the window (y ± 1 for
// x windows, x ± 1 for y windows), whose noise is independent of the window's, and
// each bin's signal is the mean of its windows' own voxels (binning by the window's
// own mean would bias both: regression to the mean). Bins are
// equal width in √mean (the Poisson part's variance-stabilizing scale); windows
// touching the type's top value left out, and bins with more than 1 % of their taps at
// 0 (where clipping at 0 could bias the variance) skipped; the line is fitted to the
// bins by weighted least squares (weights n / var², reweighted once with the fitted
// line). The offset is not identifiable from the line (b mixes it with the read
// noise), so it is given (the camera's bias; 0 for a stack whose dark level is 0).
// The background's mean: from the stack's median, the mean of the voxels whose 3×3×3
// box mean is within 3 of its noise standard deviations of it (iterated), which leaves
// the neuron and most of its dim halo out.
struct NoiseEstimate {
  double gain = 0.0;                 // a, counts per photon
  double variance_at_zero = 0.0;     // b, counts²
  double offset = 0.0;               // as given
  double read_noise = 0.0;           // √max(0, b + a · offset); includes rounding's 1/12 when the noise is continuous
  double background_mean = 0.0;      // counts
  double background_photons = 0.0;   // (background_mean − offset) / gain
  std::int64_t samples = 0;          // noise samples in the bins used
  int bins = 0;                      // bins the line was fitted to
  double mean_lo = 0.0, mean_hi = 0.0;  // the local means those bins span, counts
  double fit_rms = 0.0;              // relative rms deviation of the bins' variances from the line
  // "gain 2.01 counts/photon, read noise 3.98 counts (offset 20 given), background 5.02
  // photons/voxel (mean 30.1 counts); line fitted to 37 bins, 1.2e6 samples, means 30–812"
  [[nodiscard]] std::string describe() const;
};

// The gain rests on signal that is smooth over five voxels: structure thinner than
// that (neurites of one or two voxels) leaks into the fourth difference and biases
// the gain up (the synthetic neuron of `synth --noise raw`, gain 1: 1.23), and the
// background photons down with it; the read noise and the background's mean in counts
// come from the background and stay right (2.00 for 2; 100.5 counts for 100.5).
// Throws io::InputError naming raw.source when the stack is normalized, smaller than 5
// voxels along both x and y, has fewer than 2 usable bins (no signal range to fit a
// slope to: a constant or nearly empty stack), or the fitted slope is not positive.
[[nodiscard]] NoiseEstimate estimate_detector_noise(const io::Volume& raw, double offset = 0.0);

}  // namespace hisnegs::simulate
