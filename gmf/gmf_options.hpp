// SPDX-License-Identifier: Apache-2.0
// Options of the GMF stage (config section `gmf`): budget, optimizer choice,
// stopping, density control. Consumed by the Ceres fit (gmf/fit.*).
#pragma once

#include <cstdint>
#include <string>

#include "io/config.hpp"

namespace hisnegs::gmf {

enum class Optimizer { kLevenbergMarquardt, kLevenbergMarquardtCgnr, kDogleg, kLbfgs, kAdam };

struct GmfOptions {
  int gaussians = 20000;  // Gaussian budget K for init and density control, [1, 10^7]
  // lm | lm-cgnr | dogleg | lbfgs | adam. Default lm-cgnr: on the synthetic default
  // (3000 Gaussians) it took 0.55 s per iteration and reached 43.5 dB 3D PSNR in
  // 1.6 s, where lm with SPARSE_NORMAL_CHOLESKY took 10-21 s per iteration.
  Optimizer optimizer = Optimizer::kLevenbergMarquardtCgnr;
  double time_budget_s = 300.0;      // wall-clock limit of the whole fit, seconds, > 0
  int rounds = 6;                    // density-control rounds (solve, split/clone/prune), [1, 1000]
  int iterations_per_round = 25;     // solver iterations per round, [1, 100000]
  int max_iterations = 0;            // cap on solver iterations over all rounds; 0 = none, [0, 10^9]
  double stop_loss = 0.0;            // stop once the loss is at or below this; 0 = never, >= 0
  double mahalanobis_cutoff = 16.0;  // δ: support of a Gaussian is dᵀΣ⁻¹d <= δ (4σ), > 0
  double prune_intensity = 0.01;     // prune Gaussians with a_k below this, [0, 1)
  double split_scale = 0.8;          // Eq. 17: s_new = split_scale * s_old, (0, 1)
  double split_offset = 0.5;         // Eq. 17: mu_new = mu_old ± split_offset * s_old, [0, 2]
  bool densify = true;               // split/clone between rounds (adapt_density)
  double densify_fraction = 0.05;    // at most this share of K split, and as many cloned, per round, (0, 1]
  double clone_residual = 0.1;       // clone where V − f exceeds this (normalized units), (0, 1)
  // Share of the empty voxels sampled for the fit, [0, 1] (overrides
  // sparse_grid.background_fraction for the fit). Without samples in empty space
  // nothing stops Gaussians from spreading mass there: on op1 the 3D PSNR stayed
  // at 17 dB with 0, and reached 54 dB with 0.01.
  double background_fraction = 0.01;
  double background_weight = 1.0;  // residual weight of background samples (x 1/fraction), >= 0
  // Edge in voxels of the sample blocks that form one Ceres residual block: 8 = one
  // OpenVDB leaf, or 4, 2, 1. Ceres forms JᵀJ densely over a residual block's
  // parameter blocks, so its cost grows with samples × (Gaussians reaching the
  // block)²; 2 was the fastest per exact-LM iteration on the synthetic default
  // with 3000 Gaussians (figures in docs/benchmarks.md).
  int residual_block_voxels = 2;
  double adam_learning_rate = 0.01;  // Adam baseline step size, > 0
  std::uint64_t seed = 0;            // init jitter and sampling seed

  void validate() const;  // throws InputError("gmf.FIELD = VALUE: rule")
  template <class V>
  void visit(V&& v) {
    v("gaussians", gaussians);
    v("optimizer", optimizer,
      io::EnumNames<Optimizer>{{"lm", Optimizer::kLevenbergMarquardt},
                               {"lm-cgnr", Optimizer::kLevenbergMarquardtCgnr},
                               {"dogleg", Optimizer::kDogleg},
                               {"lbfgs", Optimizer::kLbfgs},
                               {"adam", Optimizer::kAdam}});
    v("time_budget_s", time_budget_s);
    v("rounds", rounds);
    v("iterations_per_round", iterations_per_round);
    v("max_iterations", max_iterations);
    v("stop_loss", stop_loss);
    v("mahalanobis_cutoff", mahalanobis_cutoff);
    v("prune_intensity", prune_intensity);
    v("split_scale", split_scale);
    v("split_offset", split_offset);
    v("densify", densify);
    v("densify_fraction", densify_fraction);
    v("clone_residual", clone_residual);
    v("background_fraction", background_fraction);
    v("background_weight", background_weight);
    v("residual_block_voxels", residual_block_voxels);
    v("adam_learning_rate", adam_learning_rate);
    v("seed", seed);
  }
};

}  // namespace hisnegs::gmf
