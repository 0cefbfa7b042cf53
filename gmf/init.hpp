// SPDX-License-Identifier: Apache-2.0
// Initial Gaussians for the GMF fit (report §5.1): one per occupied cell of a
// regular world-space grid over the foreground, the cell size chosen so that
// the count meets the budget; centres at the cell's intensity-weighted centroid,
// scales from the grid step, intensities from the local values. Rasterizing a
// mixture is gmf/rasterize.hpp's.
#pragma once

#include "gmf/gaussian_mixture.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

struct InitReport {
  double cell_world = 0;        // grid step, world units; cells anchored at the world origin (at the
                                // box corner -aspect when no origin-anchored grid meets the budget)
  std::int64_t foreground = 0;  // voxels above the threshold
};

// `volume` normalized; foreground = voxels > threshold. Returns at most `budget`
// Gaussians (as close to it as the grid allows). Throws io::InputError when no
// voxel is above the threshold.
GaussianMixture initialize_on_grid(const io::Volume& volume, const io::WorldFrame& frame, double threshold, int budget,
                                   InitReport* report = nullptr);

}  // namespace hisnegs::gmf
