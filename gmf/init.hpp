// SPDX-License-Identifier: Apache-2.0
// Initial Gaussians for the GMF fit (report §5.1): one per occupied cell of a
// regular world-space grid over the foreground, the cell size chosen so that the
// count meets the budget (centres at the cell's intensity-weighted centroid, scales
// from the grid step, intensities from the local values); or one per local maximum
// of the volume. Rasterizing a mixture is gmf/core/rasterize.hpp's.
#pragma once

#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/gmf_options.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

struct InitReport {
  double cell_world = 0;        // grid step, world units; cells anchored at the world origin (at the
                                // box corner -aspect when no origin-anchored grid meets the budget)
  std::int64_t foreground = 0;  // voxels above the threshold
};

// Where a grid Gaussian's intensity comes from: the mean of its cell's foreground
// voxels (right for a sum, whose terms add up) or the volume at its centre (right
// for a max-mixture, where each term alone must reach the volume).
enum class InitIntensity { kCellMean, kAtCentre };

// `volume` normalized; foreground = voxels > threshold. Returns at most `budget`
// Gaussians (as close to it as the grid allows). Throws io::InputError when no
// voxel is above the threshold.
GaussianMixture initialize_on_grid(const io::Volume& volume, const io::WorldFrame& frame, double threshold, int budget,
                                   InitReport* report = nullptr, InitIntensity intensity = InitIntensity::kCellMean);

// One Gaussian per local maximum of the foreground (no 26-neighbour brighter), the
// brightest `budget` of them, each isotropic with a = its voxel's value and σ half
// the spacing they would have spread evenly over the foreground (at least half a
// voxel). report->cell_world gets that spacing. Throws as initialize_on_grid.
GaussianMixture initialize_at_maxima(const io::Volume& volume, const io::WorldFrame& frame, double threshold,
                                     int budget, InitReport* report = nullptr);

// The fit's start as `options` ask: gmf.init (grid or maxima) with gmf.gaussians,
// grid intensities by the aggregation (cell mean for a sum, the value at the centre
// for a softmax).
GaussianMixture initialize_mixture(const io::Volume& volume, const io::WorldFrame& frame, double threshold,
                                   const GmfOptions& options, InitReport* report = nullptr);

// The fit's start from another fit of the same stack: a coarser level of its
// multiscale pyramid (the same world box, CONVENTIONS' aspect of a level is the
// stack's) or an earlier fit. `model` is in world coordinates where `frame`'s
// origin lies at `origin` (a brick's region frame: its shift; a whole stack: 0);
// the Gaussians centred inside the frame's box are kept, moved into its
// coordinates, the brightest options.gaussians of them, each scale within the
// fit's largest and each axis ratio within options.max_axis_ratio. Empty when none
// is centred inside.
GaussianMixture warm_start_mixture(const GaussianMixture& model, const io::WorldFrame& frame,
                                   const GmfOptions& options,
                                   const Eigen::Vector3d& origin = Eigen::Vector3d::Zero());

}  // namespace hisnegs::gmf
