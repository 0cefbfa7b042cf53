// SPDX-License-Identifier: Apache-2.0
// Options of the GMF stage (config section `gmf`): budget, the mixture's
// aggregation and β schedule, optimizer choice, stopping, density control.
// Consumed by the Ceres fit (gmf/fit.*).
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "gmf/core/aggregation.hpp"
#include "io/config.hpp"

namespace hisnegs::gmf {

// kCustom: GmfOptions::custom, a registered or user-given solver (gmf/round_solver.hpp);
// not a config value.
enum class Optimizer { kBrickLm, kLevenbergMarquardt, kLevenbergMarquardtCgnr, kDogleg, kLbfgs, kAdam, kCustom };

struct NamedSolver;  // gmf/round_solver.hpp

// Where the fit's Gaussians start: one per occupied cell of a regular grid over the
// foreground, or one per local maximum of the (lightly smoothed) volume.
enum class FitInit { kGrid, kMaxima };

struct GmfOptions {
  int gaussians = 20000;  // Gaussian budget K for init and density control, [1, 10^7]
  // What the mixture's value is: `softmax` fits f_β = Σ w_k g_k, w = softmax(β g)
  // (report Eq. 8 in 3D), which tends to max_k g_k, the value every MIP splat shows,
  // and ends on the max itself (hard_share); `max` fits the max from the start;
  // `sum` fits the report's Eq. 1 (density export). docs/user-guide.md says which to
  // use for what.
  Aggregation aggregation = Aggregation::kSoftmax;
  // The softmax β schedule: β of round r is min(beta_end, beta_start · beta_growth^r).
  double beta_start = 8.0;   // > 0
  double beta_end = 64.0;    // >= beta_start
  double beta_growth = 2.0;  // >= 1
  // softmax only: the share of the fit that ends on the max itself (the hard MIP's
  // 3D counterpart, gmf/core/aggregation.hpp), [0, 1): the rounds that start after
  // (1 − hard_share) of the time budget, or of gmf.rounds, whichever comes first,
  // solve f = max_k g_k with its subgradient, and the checkpoint records `max`.
  // At β alone a dim region's softmax is close to a mean, so halos that the max
  // shows were never fitted away (docs/benchmarks.md "Hard MIP"). 0: β alone.
  double hard_share = 0.25;
  // adam | brick-lm | lm | lm-cgnr | dogleg | lbfgs. brick-lm: exact LM on small
  // local problems (gmf/brick_solver.hpp), swept colour by colour; the others solve
  // one global problem per round. Adam is the default because it fits both
  // objectives best of all of them on the shared stacks (docs/benchmarks.md: the
  // brick LM beats the global Ceres solvers, but not Adam).
  Optimizer optimizer = Optimizer::kAdam;
  FitInit init = FitInit::kGrid;  // grid | maxima
  // Wall-clock limit of the whole fit, seconds, >= 0: the fit stops before it.
  // 0: no limit, the schedule alone (rounds x iterations) ends the fit, so the
  // result does not depend on the machine's speed or load (the bricked fit's
  // checkpoint is then the same on any number of threads or MPI ranks).
  double time_budget_s = 290.0;
  // The limit in seconds: time_budget_s, or a limit never reached when it is 0.
  [[nodiscard]] double budget_seconds() const { return time_budget_s > 0 ? time_budget_s : 1e9; }
  // Rounds (solve, then split/clone/prune), [1, 1000]: more than the budget allows
  // on a 2-core machine (op1: 40), so the budget, not the count, ends a default fit.
  int rounds = 60;
  // Iterations per round of the global solvers and Adam (steps), [1, 100000].
  int iterations_per_round = 40;
  int max_iterations = 0;            // cap on solver iterations over all rounds; 0 = none, [0, 10^9]
  double stop_loss = 0.0;            // stop once the loss is at or below this; 0 = never, >= 0
  double mahalanobis_cutoff = 16.0;  // δ: support of a Gaussian is dᵀΣ⁻¹d <= δ (4σ), > 0
  double prune_intensity = 0.01;     // prune Gaussians with a_k below this, [0, 1)
  double split_scale = 0.8;          // Eq. 17: s_new = split_scale * s_old, (0, 1)
  double split_offset = 0.5;         // Eq. 17: mu_new = mu_old ± split_offset * s_old, [0, 2]
  bool densify = true;               // split/clone between rounds (adapt_density)
  double densify_fraction = 0.05;    // at most this share of K split, and as many cloned, per round, (0, 1]
  double clone_residual = 0.1;       // clone where V − f exceeds this (normalized units), (0, 1)
  // Not a config field: set by the fit stage to the stack background's 99.9th
  // percentile (0 for a subtracted background), so no clone lands where noise alone
  // could explain V (clones need V above it). [0, 1).
  double clone_floor = 0.0;
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
  // Depth in voxels of the zero-valued shell sampled just outside the stack's box,
  // beyond every foreground voxel on a face (gmf/samples.hpp), [0, 8]; 0 = none.
  // The volume is 0 outside its box, as the ray-marched MIPs see it: without the
  // shell, Gaussians at a face grew out of the stack (streaks in views past it).
  int outside_voxels = 2;
  // Each round, every sample moves to a random point within ±jitter/2 voxel of its
  // voxel centre, its target the volume's trilinear value there
  // (gmf::jitter_samples), [0, 1]; 0 = voxel centres only (the report's samples).
  // On centres alone the softmax fit put bright sub-voxel Gaussians between them,
  // which every MIP view shows: op2's fit-alone views 30.5 dB at 0, 37.7 dB at 1.
  // Unset (`auto`, the default) = 1 for the softmax (the MIP model), 0 for the sum
  // (the density model, measured at voxel centres: op1's foreground 3D PSNR 52.6 dB
  // at 0, 31.2 dB at 1); docs/benchmarks.md, "Sub-voxel samples".
  std::optional<double> sample_jitter;
  // brick-lm: bricks start as cubes of this many voxels (a power of two, [2, 256])
  // and are halved while they hold more than brick_gaussians Gaussians, [1, 10^4].
  int brick_voxels = 32;
  int brick_gaussians = 32;
  int brick_iterations = 8;          // brick-lm: LM iterations per brick per round, [1, 1000]
  double adam_learning_rate = 0.01;  // Adam baseline step size, > 0
  // Largest axis ratio of a Gaussian (longest / shortest scale), kept by a projection
  // after every step and round (gmf::bound_axis_ratio): no needles fitted on noise
  // (a needle is a ratio above kNeedleAxisRatio, 20). [1.5, 1e6].
  double max_axis_ratio = 16.0;
  std::uint64_t seed = 0;            // init jitter and sampling seed
  // Stacks larger than memory: the bricked fit (gmf/bricked/bricked_fit.hpp,
  // docs/user-guide.md "Stacks larger than memory").
  // The most memory the fit may use: "auto" (half the machine's RAM) or a size
  // ("1GiB", "512MiB", "2GB", "1.5G"; K/M/G/T without B are binary). A stack whose
  // in-memory fit fits under it is fitted whole, as always; a larger one in bricks.
  std::string max_memory = "auto";
  // Edge of a brick's core in voxels, 0 or [kSmallestStreamBrick, 65536]: 0 = planned
  // from max_memory (one brick when the stack fits); > 0 = bricks of this core even
  // when it fits. A fit of more than kMostStreamBricks bricks is refused.
  int stream_brick_voxels = 0;
  static constexpr int kSmallestStreamBrick = 8;
  static constexpr int kMostStreamBricks = 20000;
  // The largest Gaussian scale of a bricked fit, in smallest voxels, [0.5, 64]: it
  // bounds a Gaussian's reach (sqrt(mahalanobis_cutoff) scales) and so the halo.
  double stream_scale_voxels = 6.0;
  int seam_iterations = 200;  // Adam steps of the seam pass per brick, [0, 100000]; 0 = no seam pass
  // Not config keys (set by the streamed fit): the largest scale in world units (0:
  // min(0.5, 32 largest voxels)), and how many Gaussians at the start of the mixture
  // are held fixed (the seam pass; Adam only, no density control).
  double max_scale_world = 0.0;
  std::size_t frozen = 0;
  // Not a config key: false = the rounds are not measured (no round's loss and
  // foreground PSNR on all its samples, no final 3D PSNR). The streamed fit's seam
  // refit discards them, and measuring every Gaussian each round was a quarter of
  // its pass; the optimizer's own per-step log (and gmf.stop_loss) stays.
  bool measure = true;
  // The largest σ the fit allows (world units) on voxels of these smallest and
  // largest edges: max_scale_world, or min(0.5, 32 largest voxels); at least 0.2
  // smallest voxel. The init starts within it and every round keeps to it.
  [[nodiscard]] double largest_scale(double min_voxel, double max_voxel) const;
  // Not a config key (set by compare-optimizers): softmax only, when > 0 every
  // logged loss is the objective at this β while the rounds follow the schedule, so
  // that runs with and without β continuation are measured on one objective. Only
  // Adam and brick-lm log at another β than they solve; 0 = each round's own β.
  double report_beta = 0.0;
  // Not a config key (set by compare-optimizers and the Python module): the solver
  // of Optimizer::kCustom, which solves every round at the round's own β.
  std::shared_ptr<const NamedSolver> custom;

  // sample_jitter, or its automatic value for this aggregation.
  [[nodiscard]] double jitter() const;
  // The mixture model of round `round` (its β from the schedule; the max when
  // `hard`, the hard share, for a softmax fit).
  [[nodiscard]] MixtureModel model(int round, bool hard = false) const;
  // Whether round `round`, starting `seconds` into the fit, is in the hard share.
  [[nodiscard]] bool hard_round(int round, double seconds) const;
  // How the fitted mixture is evaluated: the max after a hard share, else aggregation.
  [[nodiscard]] Aggregation final_aggregation() const;
  // The model every logged loss is measured with: model(round), at report_beta when set.
  [[nodiscard]] MixtureModel report_model(int round, bool hard = false) const;
  void validate() const;  // throws InputError("gmf.FIELD = VALUE: rule")
  template <class V>
  void visit(V&& v) {
    v("gaussians", gaussians);
    v("aggregation", aggregation,
      io::EnumNames<Aggregation>{
          {"softmax", Aggregation::kSoftmax}, {"sum", Aggregation::kSum}, {"max", Aggregation::kMax}});
    v("beta_start", beta_start);
    v("beta_end", beta_end);
    v("beta_growth", beta_growth);
    v("hard_share", hard_share);
    v("optimizer", optimizer,
      io::EnumNames<Optimizer>{{"brick-lm", Optimizer::kBrickLm},
                               {"lm", Optimizer::kLevenbergMarquardt},
                               {"lm-cgnr", Optimizer::kLevenbergMarquardtCgnr},
                               {"dogleg", Optimizer::kDogleg},
                               {"lbfgs", Optimizer::kLbfgs},
                               {"adam", Optimizer::kAdam}});
    v("init", init, io::EnumNames<FitInit>{{"grid", FitInit::kGrid}, {"maxima", FitInit::kMaxima}});
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
    v("outside_voxels", outside_voxels);
    v("sample_jitter", sample_jitter);
    v("brick_voxels", brick_voxels);
    v("brick_gaussians", brick_gaussians);
    v("brick_iterations", brick_iterations);
    v("adam_learning_rate", adam_learning_rate);
    v("max_axis_ratio", max_axis_ratio);
    v("seed", seed);
    v("max_memory", max_memory);
    v("stream_brick_voxels", stream_brick_voxels);
    v("stream_scale_voxels", stream_scale_voxels);
    v("seam_iterations", seam_iterations);
  }
};

}  // namespace hisnegs::gmf
