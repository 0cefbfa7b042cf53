// SPDX-License-Identifier: Apache-2.0
// The GMF loss ½ Σ w² (f − V)² over every residual block and its gradient with
// respect to all parameters (flat: Gaussian k's at kGaussianParamCount × k, in
// GaussianParam order), for the first-order optimizers (L-BFGS, Adam). Built
// from the same BlockCost blocks as the least-squares problem. Ceres stays in the .cpp.
#pragma once

#include <cstdint>
#include <memory>
#include <vector>

#include "gmf/core/aggregation.hpp"
#include "gmf/block_index.hpp"
#include "gmf/samples.hpp"

namespace hisnegs::gmf {

class FitObjective {
 public:
  // Keeps references to `samples` and `index`; `model` says how terms combine.
  FitObjective(const SampleSet& samples, const BlockIndex& index, std::size_t gaussians, const MixtureModel& model);
  ~FitObjective();
  FitObjective(const FitObjective&) = delete;
  FitObjective& operator=(const FitObjective&) = delete;

  // Loss at `params` (kGaussianParamCount × K values); fills `gradient` (as many)
  // when not null, and `foreground_se` with Σ (f − V)² over the foreground samples
  // (the sparse grid's foreground and band) when not null. TBB-parallel over fixed
  // chunks of residual blocks, combined in chunk order (deterministic).
  double evaluate(const double* params, double* gradient, double* foreground_se = nullptr) const;
  [[nodiscard]] std::size_t parameters() const { return kGaussianParamCount * gaussians_; }
  // ½ Σ (w V)² of the samples no Gaussian reaches (included in evaluate()); after
  // hold_fixed, also ½ Σ w² (f − V)² of those only held Gaussians reach.
  [[nodiscard]] double constant() const { return constant_; }

  // Holds Gaussians [0, frozen) fixed at their values in `params`: their terms at
  // every sample are combined once (PointTerms), the sample blocks only they reach
  // join the constant, and evaluate() then reads and differentiates the others
  // alone (the held ones' entries of `params` are not read; their gradient is 0).
  // The value is the same function as before (up to rounding: the held terms are
  // combined first). For a seam refit, where most Gaussians are neighbours held
  // fixed, a step costs what the free ones reach. Once per objective.
  void hold_fixed(const double* params, std::size_t frozen);
  [[nodiscard]] std::size_t held() const;

 private:
  struct Blocks;
  std::unique_ptr<Blocks> blocks_;
  std::size_t gaussians_;
  double constant_ = 0;
  double constant_foreground_se_ = 0;  // Σ (f − V)² of the foreground samples no free Gaussian reaches
};

// The residuals of every sample, r_j = w_j (f(x_j) − V_j) in sample order, and
// (when `with_jacobian`) their Jacobian with respect to all parameters in CSR form:
// row j holds the kGaussianParamCount columns of each Gaussian `index` lists for
// sample j's block, ascending (explicit zeros where one does not reach the sample),
// from BlockCost's analytic derivatives. ½ Σ r² is FitObjective::evaluate's loss
// and Jᵀ r its gradient. Memory: samples × listed Gaussians × 11 doubles.
struct SampleResiduals {
  std::vector<double> residuals;
  std::vector<std::int64_t> row_begin;  // samples + 1
  std::vector<std::int64_t> columns;
  std::vector<double> values;
};
[[nodiscard]] SampleResiduals sample_residuals(const SampleSet& samples, const BlockIndex& index,
                                               const MixtureModel& model, const double* params, bool with_jacobian);

}  // namespace hisnegs::gmf
