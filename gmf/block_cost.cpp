// SPDX-License-Identifier: Apache-2.0
// BlockCost::Evaluate: per sample, the free Gaussians' terms and gradients, their
// aggregation with the fixed terms, the residual and its analytic Jacobian.
#include <algorithm>
#include <vector>

#include "gmf/detail/block_cost.hpp"
#include "gmf/gaussian_math.hpp"

namespace hisnegs::gmf::detail {

BlockCost::BlockCost(const SampleSet& samples, std::size_t block, std::size_t gaussians, const MixtureModel& model,
                     std::span<const PointTerms<double>> fixed)
    : samples_(samples),
      first_(samples.block_begin[block]),
      count_(samples.block_begin[block + 1] - samples.block_begin[block]),
      gaussians_(gaussians),
      model_(model),
      fixed_(fixed) {
  set_num_residuals(static_cast<int>(count_));
  mutable_parameter_block_sizes()->assign(gaussians_, kGaussianParamCount);
}

bool BlockCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  // Per-Gaussian frames and per-sample terms (thread_local scratch: Ceres evaluates
  // blocks in parallel).
  thread_local std::vector<GaussianFrame<double>> frames;
  thread_local std::vector<std::uint32_t> reach;  // the free Gaussians reaching the sample
  thread_local std::vector<double> terms, grads;  // their g and ∂g/∂θ
  frames.resize(gaussians_);
  reach.resize(gaussians_);
  terms.resize(gaussians_);
  grads.resize(gaussians_ * kGaussianParamCount);
  for (std::size_t g = 0; g < gaussians_; ++g) prepare_gaussian(parameters[g], frames[g]);
  if (jacobians) {
    for (std::size_t g = 0; g < gaussians_; ++g) {
      if (jacobians[g])
        std::fill(jacobians[g], jacobians[g] + static_cast<std::size_t>(count_) * kGaussianParamCount, 0.0);
    }
  }
  const bool soft = model_.aggregation == Aggregation::kSoftmax;
  for (std::uint32_t j = 0; j < count_; ++j) {
    const std::size_t s = first_ + j;
    const double x[3] = {samples_.x[s], samples_.y[s], samples_.z[s]};
    const double w = samples_.weight[s];
    PointTerms<double> all = fixed_.empty() ? no_terms<double>() : fixed_[j];  // the fixed terms, then the free
    std::size_t n = 0;
    for (std::size_t g = 0; g < gaussians_; ++g) {
      double z[3];
      if (mahalanobis(frames[g], x, z) > model_.cutoff) continue;  // outside the support: contributes nothing
      const double term = evaluate_gaussian(frames[g], x, jacobians ? &grads[n * kGaussianParamCount] : nullptr);
      add_term(all, term, model_);
      reach[n] = static_cast<std::uint32_t>(g);
      terms[n++] = term;
    }
    const double f = terms_value(all, model_);
    residuals[j] = w * (f - samples_.value[s]);
    if (!jacobians) continue;
    for (std::size_t i = 0; i < n; ++i) {
      const double df_dg = soft ? softmax_dvalue_dterm(terms[i], model_.beta, all.soft.m, all.soft.S, f) : 1.0;
      const double* grad = &grads[i * kGaussianParamCount];
      double* J = jacobians[reach[i]];
      if (!J) continue;
      const double k = w * df_dg;
      for (int c = 0; c < kGaussianParamCount; ++c) J[j * kGaussianParamCount + c] = k * grad[c];
    }
  }
  return true;
}

}  // namespace hisnegs::gmf::detail
