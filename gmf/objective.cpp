// SPDX-License-Identifier: Apache-2.0
// FitObjective: BrickCost residuals and Jacobians reduced to a loss and a gradient.
#include "gmf/objective.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "gmf/detail/brick_cost.hpp"
#include "gmf/gaussian_math.hpp"

namespace hisnegs::gmf {

struct FitObjective::Blocks {
  std::vector<std::unique_ptr<detail::BrickCost>> costs;
  std::vector<std::vector<std::uint32_t>> gaussians;  // per cost
};

FitObjective::FitObjective(const SampleSet& samples, const BrickIndex& index, std::size_t gaussians, double cutoff)
    : blocks_(std::make_unique<Blocks>()), gaussians_(gaussians) {
  constant_ = unreached_loss(samples, index);
  for (std::size_t b = 0; b < samples.bricks(); ++b) {
    const auto ids = index.of(b);
    if (ids.empty()) continue;
    blocks_->costs.push_back(std::make_unique<detail::BrickCost>(samples, b, ids, cutoff));
    blocks_->gaussians.emplace_back(ids.begin(), ids.end());
  }
}

FitObjective::~FitObjective() = default;

double FitObjective::evaluate(const double* params, double* gradient) const {
  // Fixed chunks of residual blocks, each reduced sequentially into its own buffer
  // and combined in chunk order: the result does not depend on thread scheduling.
  constexpr std::size_t kChunks = 8;
  const std::size_t n = parameters();
  const std::size_t blocks = blocks_->costs.size();
  std::vector<double> chunk_loss(kChunks, 0.0);
  std::vector<std::vector<double>> chunk_grad(kChunks);
  tbb::parallel_for(std::size_t{0}, kChunks, [&](std::size_t chunk) {
    const std::size_t begin = blocks * chunk / kChunks, end = blocks * (chunk + 1) / kChunks;
    double loss = 0;
    std::vector<double>& grad = chunk_grad[chunk];
    if (gradient) grad.assign(n, 0.0);
    std::vector<const double*> p;
    std::vector<double> residuals, jac_storage;
    std::vector<double*> jac;
    for (std::size_t c = begin; c < end; ++c) {
      const detail::BrickCost& cost = *blocks_->costs[c];
      const auto& ids = blocks_->gaussians[c];
      p.clear();
      for (std::uint32_t k : ids) {
        const double* g = params + kGaussianParamCount * static_cast<std::size_t>(k);
        p.push_back(g + kMeanX);
        p.push_back(g + kLogScale0);
        p.push_back(g + kRotW);
        p.push_back(g + kLogit);
      }
      const int nr = cost.num_residuals();
      residuals.resize(nr);
      if (gradient) {
        jac_storage.resize(static_cast<std::size_t>(nr) * kGaussianParamCount * ids.size());
        jac.resize(ids.size() * detail::kBlocksPerGaussian);
        std::size_t offset = 0;
        for (std::size_t i = 0; i < jac.size(); ++i) {
          jac[i] = jac_storage.data() + offset;
          offset += static_cast<std::size_t>(nr) * detail::kBlockSizes[i % detail::kBlocksPerGaussian];
        }
      }
      cost.Evaluate(p.data(), residuals.data(), gradient ? jac.data() : nullptr);
      for (double r_j : residuals) loss += 0.5 * r_j * r_j;
      if (!gradient) continue;
      // ∇ = Σ_j r_j ∂r_j/∂θ, block by block.
      for (std::size_t g = 0; g < ids.size(); ++g) {
        double* out = grad.data() + kGaussianParamCount * static_cast<std::size_t>(ids[g]);
        int param = 0;
        for (int b = 0; b < detail::kBlocksPerGaussian; ++b) {
          const double* J = jac[g * detail::kBlocksPerGaussian + b];
          const int size = detail::kBlockSizes[b];
          for (int j = 0; j < nr; ++j) {
            for (int c2 = 0; c2 < size; ++c2) out[param + c2] += residuals[j] * J[j * size + c2];
          }
          param += size;
        }
      }
    }
    chunk_loss[chunk] = loss;
  });
  double loss = constant_;
  if (gradient) std::fill(gradient, gradient + n, 0.0);
  for (std::size_t chunk = 0; chunk < kChunks; ++chunk) {
    loss += chunk_loss[chunk];
    if (gradient) {
      for (std::size_t i = 0; i < n; ++i) gradient[i] += chunk_grad[chunk][i];
    }
  }
  return loss;
}

}  // namespace hisnegs::gmf
