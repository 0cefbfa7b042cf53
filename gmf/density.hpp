// SPDX-License-Identifier: Apache-2.0
// Adaptive density control between GMF fit rounds (report §5.1 and Eq. 17):
// split the Gaussians that carry concentrated residual error, clone new ones
// into under-covered foreground, within the Gaussian budget. Pruning (a < 0.01)
// is done by the fit itself. Knows no solver.
#pragma once

#include "gmf/block_index.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/gmf_options.hpp"
#include "gmf/samples.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

struct DensityChange {
  int split = 0;   // Gaussians replaced by two (Eq. 17)
  int cloned = 0;  // Gaussians added at under-covered samples
};

// `index` must be current for `mixture` (no padding needed); f is `model`'s value.
// Appends to `mixture`. Error of Gaussian k: Σ_j share_k(x_j) r_j², its share of
// each sample's squared residual: g_k / f for a sum, its softmax weight for a
// max-mixture (the Gaussian that shows there). Split: the largest-error Gaussians
// (error above mean + 2 sd, largest scale above one voxel) become two at
// μ ± split_offset s_max along the longest axis with scales × split_scale. Clone:
// foreground samples with V − f > gmf.clone_residual and V above gmf.clone_floor
// (the background's noise ceiling: no clone on a noise peak), strongest first, at least two
// voxels apart, each a new isotropic Gaussian of one voxel with a = V − f (sum) or
// a = V (softmax: it shows alone). At most gmf.densify_fraction × K of each per
// call, and never past gmf.gaussians.
DensityChange adapt_density(GaussianMixture& mixture, const SampleSet& samples, const BlockIndex& index,
                            const io::WorldFrame& frame, const GmfOptions& options, const MixtureModel& model);

}  // namespace hisnegs::gmf
