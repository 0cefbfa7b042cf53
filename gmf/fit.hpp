// SPDX-License-Identifier: Apache-2.0
// The GMF fit (report §2.1, §5): least squares of the mixture against the
// volume's sparse samples with Ceres, in rounds; between rounds the block index
// is rebuilt, faint Gaussians are pruned and density control splits and clones
// (gmf/density.hpp). Ceres is used here (fit.cpp), by the brick sweep
// (brick_solver.cpp) and the Jacobian probe (jacobian_probe.cpp), through the cost
// of gmf/detail/block_cost.hpp; the rest of gmf knows nothing of it.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/gmf_options.hpp"
#include "gmf/core/rasterize.hpp"
#include "gmf/samples.hpp"
#include "io/sparse_grid.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

// One line of the fit log: one solver iteration, or a round's end (psnr_fg set),
// or the final measurement (psnr_3d set).
struct FitIteration {
  int round = 0;
  int iteration = 0;    // cumulative solver iterations
  double seconds = 0;   // wall clock since the fit started (the final measurement excluded)
  double loss = 0;      // ½ Σ w² (f − V)² over all samples, f at the round's β
  double psnr_fg = -1;  // over the foreground samples (the sparse grid's foreground and band); < 0 when not computed
  double psnr_3d = -1;  // over all voxels; < 0 when not computed at this line
  int gaussians = 0;    // K
  double beta = 0;      // the round's softmax β (0 for a sum)
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
  double seconds = 0;            // wall clock of the fit, within gmf.time_budget_s
  double measuring_seconds = 0;  // the final all-voxel 3D PSNR, after the fit
  double final_psnr_3d = 0;      // all voxels, the model's own aggregation at final_beta
  double final_psnr_fg = 0;      // foreground samples, at the voxel centres (not moved)
  double final_beta = 0;         // β of the last round (0 for a sum)
  int pruned = 0;
  std::string stop_reason;
};

// The fit's samples of `grid` (gmf.background_weight, residual_block_voxels,
// outside_voxels). Once they are taken the grid is no longer needed: on a large
// stack its scattered background leaves are as large as the volume, so callers
// that keep the fit's memory low drop it before fitting.
[[nodiscard]] SampleSet fit_samples(const io::SparseGrid& grid, const GmfOptions& options);

// Fits `mixture` (modified in place) to `volume` (normalized, in `frame`) using
// `samples` (fit_samples()), with gmf.aggregation (sum, or softmax along the β
// schedule). Optimizers: brick-lm (gmf/brick_solver.hpp), lm, lm-cgnr, dogleg
// (one global Ceres least-squares problem per round), lbfgs (ceres::GradientProblem)
// and adam. No solver starts work after gmf.time_budget_s; the final 3D PSNR is
// measured after it.
// `on_progress` is called for every log line.
FitResult fit_mixture(const io::Volume& volume, const SampleSet& samples, const io::WorldFrame& frame,
                      GaussianMixture& mixture, const GmfOptions& options,
                      const std::function<void(const FitIteration&)>& on_progress = {});
// What the fit's rounds need of the stack besides its samples: the values at samples
// moved within their voxels (gmf.jitter > 0) and, after the last round, the 3D PSNR
// over every voxel. stack_access() reads a dense stack in memory (which must outlive
// the fit); a caller that holds the stack otherwise (by regions, on other ranks)
// provides its own and drives the same round loop.
struct StackAccess {
  std::function<SampleSet(const SampleSet& centres, double jitter, std::uint64_t seed)> jittered;
  std::function<double(const GaussianMixture& mixture, const RasterizeOptions& options)> psnr_3d;
};
[[nodiscard]] StackAccess stack_access(const io::Volume& volume, const io::WorldFrame& frame);

// fit_mixture with the stack reached through `stack`.
FitResult fit_mixture(const StackAccess& stack, const SampleSet& samples, const io::WorldFrame& frame,
                      GaussianMixture& mixture, const GmfOptions& options,
                      const std::function<void(const FitIteration&)>& on_progress = {});

// The same with fit_samples(grid, options) in grid.frame().
FitResult fit_mixture(const io::Volume& volume, const io::SparseGrid& grid, GaussianMixture& mixture,
                      const GmfOptions& options, const std::function<void(const FitIteration&)>& on_progress = {});

}  // namespace hisnegs::gmf
