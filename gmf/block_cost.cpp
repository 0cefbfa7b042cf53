// SPDX-License-Identifier: Apache-2.0
// BlockCost::Evaluate: per sample, the free Gaussians' terms and gradients, their
// aggregation with the fixed terms, the residual and its analytic Jacobian.
#include <algorithm>
#include <stdexcept>
#include <string>
#include <vector>

#include "gmf/detail/block_cost.hpp"
#include "gmf/block_index.hpp"
#include "gmf/objective.hpp"
#include "gmf/core/gaussian_math.hpp"

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
      const double df_dg = dvalue_dterm(terms[i], all, model_, f);
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

namespace hisnegs::gmf {

SampleResiduals sample_residuals(const SampleSet& samples, const BlockIndex& index, const MixtureModel& model,
                                 const double* params, bool with_jacobian) {
  SampleResiduals out;
  const std::size_t n = samples.size();
  out.residuals.assign(n, 0.0);
  out.row_begin.assign(n + 1, 0);
  std::vector<const double*> blocks;
  std::vector<double> jac;
  std::vector<double*> jac_rows;
  for (std::size_t b = 0; b < samples.blocks(); ++b) {
    const std::span<const std::uint32_t> ids = index.of(b);
    const std::uint32_t s0 = samples.block_begin[b], s1 = samples.block_begin[b + 1];
    const std::size_t count = s1 - s0;
    if (ids.empty()) {  // nothing reaches the block: f = 0
      for (std::uint32_t s = s0; s < s1; ++s) out.residuals[s] = -samples.weight[s] * samples.value[s];
      for (std::uint32_t s = s0; s < s1; ++s) out.row_begin[s + 1] = out.row_begin[s];
      continue;
    }
    const detail::BlockCost cost(samples, b, ids.size(), model);
    blocks.resize(ids.size());
    for (std::size_t i = 0; i < ids.size(); ++i) blocks[i] = params + kGaussianParamCount * ids[i];
    jac.resize(with_jacobian ? ids.size() * count * kGaussianParamCount : 0);
    jac_rows.resize(ids.size());
    for (std::size_t i = 0; i < ids.size(); ++i) jac_rows[i] = jac.data() + i * count * kGaussianParamCount;
    if (!cost.Evaluate(blocks.data(), out.residuals.data() + s0, with_jacobian ? jac_rows.data() : nullptr)) {
      throw std::runtime_error("sample_residuals: block " + std::to_string(b) + " could not be evaluated");
    }
    for (std::uint32_t s = s0; s < s1; ++s) {
      const std::size_t j = s - s0;
      out.row_begin[s + 1] = out.row_begin[s] + (with_jacobian ? static_cast<std::int64_t>(ids.size() * kGaussianParamCount) : 0);
      if (!with_jacobian) continue;
      for (std::size_t i = 0; i < ids.size(); ++i) {
        for (std::size_t c = 0; c < kGaussianParamCount; ++c) {
          out.columns.push_back(static_cast<std::int64_t>(kGaussianParamCount * ids[i] + c));
          out.values.push_back(jac_rows[i][j * kGaussianParamCount + c]);
        }
      }
    }
  }
  return out;
}

}  // namespace hisnegs::gmf
