// SPDX-License-Identifier: Apache-2.0
// The GMF fit (report §2.1, §5): least squares of the mixture against the
// volume's sparse samples with Ceres, in rounds; between rounds the brick index
// is rebuilt, faint Gaussians are pruned and density control splits and clones
// (gmf/density.hpp). Ceres stays inside fit.cpp.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "gmf/gaussian_mixture.hpp"
#include "gmf/gmf_options.hpp"
#include "io/sparse_grid.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

// One line of the fit log (one solver iteration, or a round's end when psnr_3d is set).
struct FitIteration {
  int round = 0;
  int iteration = 0;    // cumulative solver iterations
  double seconds = 0;   // wall clock since the fit started, without measuring (FitResult::measuring_seconds)
  double loss = 0;      // ½ Σ w² (f − V)² over all samples
  double psnr_3d = -1;  // over all voxels; < 0 when not computed at this line
  int gaussians = 0;    // K
};

// What density control did at the end of a round.
struct FitRound {
  int round = 0;
  int pruned = 0, split = 0, cloned = 0;
  int gaussians = 0;  // K after all three
};

struct FitResult {
  std::vector<FitIteration> log;
  std::vector<FitRound> rounds;
  double seconds = 0;            // wall clock of the fit without measuring_seconds
  double measuring_seconds = 0;  // spent on the 3D PSNR after each round (not charged to the optimizer)
  double final_psnr_3d = 0;
  int pruned = 0;
  std::string stop_reason;
};

// Fits `mixture` (modified in place) to `volume` (normalized) using the samples of
// `grid`. `on_progress` is called for every log line. Optimizers: lm, lm-cgnr,
// dogleg (Ceres least squares), lbfgs (ceres::GradientProblem) and adam.
FitResult fit_mixture(const io::Volume& volume, const io::SparseGrid& grid, GaussianMixture& mixture,
                      const GmfOptions& options, const std::function<void(const FitIteration&)>& on_progress = {});

}  // namespace hisnegs::gmf
