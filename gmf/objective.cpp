// SPDX-License-Identifier: Apache-2.0
// FitObjective: BlockCost residuals and Jacobians reduced to a loss and a gradient.
#include "gmf/objective.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "gmf/detail/block_cost.hpp"
#include "gmf/gaussian_math.hpp"

namespace hisnegs::gmf {

struct FitObjective::Blocks {
  const SampleSet* samples = nullptr;
  std::vector<std::unique_ptr<detail::BlockCost>> costs;
  std::vector<std::vector<std::uint32_t>> gaussians;  // per cost
  std::vector<bool> foreground;                       // per cost: its samples are foreground
  std::vector<std::size_t> block;                     // per cost: its sample block
};

FitObjective::FitObjective(const SampleSet& samples, const BlockIndex& index, std::size_t gaussians,
                           const MixtureModel& model)
    : blocks_(std::make_unique<Blocks>()), gaussians_(gaussians) {
  constant_ = unreached_loss(samples, index);
  for (std::size_t b = 0; b < samples.blocks(); ++b) {
    const auto ids = index.of(b);
    const bool foreground = samples.block_begin[b] < samples.foreground;  // blocks hold one part only
    if (ids.empty()) {
      if (foreground) {
        for (std::uint32_t s = samples.block_begin[b]; s < samples.block_begin[b + 1]; ++s) {
          unreached_foreground_se_ += samples.value[s] * samples.value[s];
        }
      }
      continue;
    }
    blocks_->costs.push_back(std::make_unique<detail::BlockCost>(samples, b, ids.size(), model));
    blocks_->gaussians.emplace_back(ids.begin(), ids.end());
    blocks_->foreground.push_back(foreground);
    blocks_->block.push_back(b);
  }
  blocks_->samples = &samples;
}

FitObjective::~FitObjective() = default;

double FitObjective::evaluate(const double* params, double* gradient, double* foreground_se) const {
  // Fixed chunks of residual blocks, each reduced sequentially into its own buffer
  // and combined in chunk order: the result does not depend on thread scheduling.
  constexpr std::size_t kChunks = 8;
  const std::size_t n = parameters();
  const std::size_t blocks = blocks_->costs.size();
  std::vector<double> chunk_loss(kChunks, 0.0), chunk_fg(kChunks, 0.0);
  std::vector<std::vector<double>> chunk_grad(kChunks);
  tbb::parallel_for(std::size_t{0}, kChunks, [&](std::size_t chunk) {
    const std::size_t begin = blocks * chunk / kChunks, end = blocks * (chunk + 1) / kChunks;
    double loss = 0, fg = 0;
    std::vector<double>& grad = chunk_grad[chunk];
    if (gradient) grad.assign(n, 0.0);
    std::vector<const double*> p;
    std::vector<double> residuals, jac_storage;
    std::vector<double*> jac;
    for (std::size_t c = begin; c < end; ++c) {
      const detail::BlockCost& cost = *blocks_->costs[c];
      const auto& ids = blocks_->gaussians[c];
      p.clear();
      for (std::uint32_t k : ids) p.push_back(params + kGaussianParamCount * static_cast<std::size_t>(k));
      const int nr = cost.num_residuals();
      residuals.resize(nr);
      if (gradient) {
        jac_storage.resize(static_cast<std::size_t>(nr) * kGaussianParamCount * ids.size());
        jac.resize(ids.size());
        for (std::size_t i = 0; i < jac.size(); ++i) {
          jac[i] = jac_storage.data() + i * static_cast<std::size_t>(nr) * kGaussianParamCount;
        }
      }
      cost.Evaluate(p.data(), residuals.data(), gradient ? jac.data() : nullptr);
      for (double r_j : residuals) loss += 0.5 * r_j * r_j;
      if (foreground_se && blocks_->foreground[c]) {
        const SampleSet& sm = *blocks_->samples;
        const std::uint32_t first = sm.block_begin[blocks_->block[c]];
        for (int j = 0; j < nr; ++j) {
          const double d = residuals[j] / sm.weight[first + j];  // f − V
          fg += d * d;
        }
      }
      if (!gradient) continue;
      // ∇ = Σ_j r_j ∂r_j/∂θ, Gaussian by Gaussian.
      for (std::size_t g = 0; g < ids.size(); ++g) {
        double* out = grad.data() + kGaussianParamCount * static_cast<std::size_t>(ids[g]);
        const double* J = jac[g];
        for (int j = 0; j < nr; ++j) {
          for (int c2 = 0; c2 < kGaussianParamCount; ++c2) out[c2] += residuals[j] * J[j * kGaussianParamCount + c2];
        }
      }
    }
    chunk_loss[chunk] = loss;
    chunk_fg[chunk] = fg;
  });
  double loss = constant_;
  if (foreground_se) *foreground_se = unreached_foreground_se_;
  if (gradient) std::fill(gradient, gradient + n, 0.0);
  for (std::size_t chunk = 0; chunk < kChunks; ++chunk) {
    loss += chunk_loss[chunk];
    if (foreground_se) *foreground_se += chunk_fg[chunk];
    if (gradient) {
      for (std::size_t i = 0; i < n; ++i) gradient[i] += chunk_grad[chunk][i];
    }
  }
  return loss;
}

}  // namespace hisnegs::gmf
