// SPDX-License-Identifier: Apache-2.0
// The Ceres residual block of one sample brick: r_j = w_j (f_δ(x_j) − V_j) over
// the brick's samples, f_δ the sum of the brick's Gaussians that reach x_j
// (m <= δ), with the analytic Jacobian of gaussian_math.hpp. Parameter blocks:
// for each Gaussian in order, mean (3), log-scales (3), quaternion (4), logit (1).
// Includes Ceres: for gmf's .cpp files and tests only.
#pragma once

#include <ceres/ceres.h>

#include <cstdint>
#include <span>
#include <vector>

#include "gmf/gaussian_math.hpp"
#include "gmf/samples.hpp"

namespace hisnegs::gmf::detail {

inline constexpr int kBlocksPerGaussian = 4;
inline constexpr int kBlockSizes[kBlocksPerGaussian] = {3, 3, 4, 1};

class BrickCost final : public ceres::CostFunction {
 public:
  // Keeps references to `samples`; `gaussians` is copied (its count fixes the blocks).
  BrickCost(const SampleSet& samples, std::size_t brick, std::span<const std::uint32_t> gaussians, double cutoff);

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override;

  [[nodiscard]] std::size_t gaussian_count() const { return gaussians_; }

 private:
  const SampleSet& samples_;
  std::uint32_t first_, count_;
  std::size_t gaussians_;
  double cutoff_;
};

// The same residuals as BrickCost as a templated functor, for Ceres' automatic
// (DynamicAutoDiffCostFunction) and numeric differentiation: benchmarks and
// cross-checks only; the fit uses BrickCost's analytic Jacobian.
struct BrickResiduals {
  const SampleSet* samples;
  std::uint32_t first, count;
  std::size_t gaussians;
  double cutoff;

  template <class T>
  bool operator()(T const* const* parameters, T* residuals) const {
    std::vector<GaussianFrame<T>> frames(gaussians);
    for (std::size_t g = 0; g < gaussians; ++g) {
      const T* const* p = parameters + kBlocksPerGaussian * g;
      prepare_gaussian(p[0], p[1], p[2], p[3][0], frames[g]);
    }
    for (std::uint32_t j = 0; j < count; ++j) {
      const std::size_t s = first + j;
      const T x[3] = {T(samples->x[s]), T(samples->y[s]), T(samples->z[s])};
      T f(0.0);
      for (std::size_t g = 0; g < gaussians; ++g) {
        T z[3];
        if (mahalanobis(frames[g], x, z) > T(cutoff)) continue;
        f += evaluate_gaussian<T>(frames[g], x, nullptr);
      }
      residuals[j] = T(samples->weight[s]) * (f - T(samples->value[s]));
    }
    return true;
  }
};

}  // namespace hisnegs::gmf::detail
