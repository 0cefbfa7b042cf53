// SPDX-License-Identifier: Apache-2.0
// The Ceres residual block of one sample block: r_j = w_j (f(x_j) − V_j) over the
// block's samples, f the model's aggregation (sum, or softmax at β) of the terms
// g_k(x_j) = a_k exp(−m_k/2) of the Gaussians that reach x_j (m <= δ): the block's
// free Gaussians (the parameter blocks) and, optionally, per sample, the terms of
// Gaussians held fixed. Analytic Jacobian: ∂f/∂g_k (1, or w_k (1 + β (g_k − f)))
// times ∂g_k/∂θ of gaussian_math.hpp. Parameter blocks: for each free Gaussian in
// order, all its kGaussianParamCount parameters as one block.
// Includes Ceres: for gmf's .cpp files and tests only.
#pragma once

#include <ceres/ceres.h>
#include <ceres/manifold.h>
#include <ceres/product_manifold.h>

#include <cstdint>
#include <span>
#include <vector>

#include "gmf/core/aggregation.hpp"
#include "gmf/core/gaussian_math.hpp"
#include "gmf/samples.hpp"

namespace hisnegs::gmf::detail {

// One parameter block per Gaussian: its kGaussianParamCount values in GaussianParam
// order (the Jacobian's 11 columns of a Gaussian are then one dense block, which
// Ceres' sparse normal equations handle far faster than four small ones).
inline constexpr int kBlocksPerGaussian = 1;
inline constexpr int kBlockSizes[kBlocksPerGaussian] = {kGaussianParamCount};

// The manifold of a Gaussian's parameter block: mean and log-scales Euclidean, the
// quaternion on the unit sphere (Ceres' QuaternionManifold), the logit Euclidean.
using GaussianManifold =
    ceres::ProductManifold<ceres::EuclideanManifold<6>, ceres::QuaternionManifold, ceres::EuclideanManifold<1>>;

// Adds one Gaussian's parameter block `p` to `problem` on `manifold`, its mean and
// log-scales boxed to [lower, upper] (kGaussianParamCount entries each, GaussianParam
// order; the quaternion and logit are not bounded).
inline void add_gaussian_block(ceres::Problem& problem, double* p, ceres::Manifold* manifold, const double* lower,
                               const double* upper) {
  problem.AddParameterBlock(p, kGaussianParamCount, manifold);
  for (int c : {kMeanX, kMeanY, kMeanZ, kLogScale0, kLogScale1, kLogScale2}) {
    problem.SetParameterLowerBound(p, c, lower[c]);
    problem.SetParameterUpperBound(p, c, upper[c]);
  }
}

class BlockCost final : public ceres::CostFunction {
 public:
  // Keeps references to `samples` and `fixed`; `gaussians` (free) only fixes the
  // block count. `fixed`, when not empty, holds one entry per sample of the block.
  BlockCost(const SampleSet& samples, std::size_t block, std::size_t gaussians, const MixtureModel& model,
            std::span<const PointTerms<double>> fixed = {});

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

  [[nodiscard]] std::size_t gaussian_count() const { return gaussians_; }

 private:
  const SampleSet& samples_;
  std::uint32_t first_, count_;
  std::size_t gaussians_;
  MixtureModel model_;
  std::span<const PointTerms<double>> fixed_;
};

// The same residuals as BlockCost as a templated functor, for Ceres' automatic
// (DynamicAutoDiffCostFunction) and numeric differentiation: benchmarks and
// cross-checks only; the fit uses BlockCost's analytic Jacobian.
struct BlockResiduals {
  const SampleSet* samples;
  std::uint32_t first, count;
  std::size_t gaussians;
  MixtureModel model;
  std::span<const PointTerms<double>> fixed;

  template <class T>
  bool operator()(T const* const* parameters, T* residuals) const {
    std::vector<GaussianFrame<T>> frames(gaussians);
    for (std::size_t g = 0; g < gaussians; ++g) {
      prepare_gaussian(parameters[g], frames[g]);
    }
    for (std::uint32_t j = 0; j < count; ++j) {
      const std::size_t s = first + j;
      const T x[3] = {T(samples->x[s]), T(samples->y[s]), T(samples->z[s])};
      const PointTerms<double> fx = fixed.empty() ? no_terms<double>() : fixed[j];
      PointTerms<T> all{T(fx.sum), {T(fx.soft.m), T(fx.soft.S), T(fx.soft.W)}, T(fx.max)};
      for (std::size_t g = 0; g < gaussians; ++g) {
        T z[3];
        if (mahalanobis(frames[g], x, z) > T(model.cutoff)) continue;
        const T term = evaluate_gaussian<T>(frames[g], x, nullptr);
        add_term(all, term, model);
      }
      const T f = terms_value(all, model);
      residuals[j] = T(samples->weight[s]) * (f - T(samples->value[s]));
    }
    return true;
  }
};

}  // namespace hisnegs::gmf::detail
