// SPDX-License-Identifier: Apache-2.0
// BrickCost::Evaluate: value and analytic Jacobian per sample and Gaussian.
#include <algorithm>
#include <vector>

#include "gmf/detail/brick_cost.hpp"
#include "gmf/gaussian_math.hpp"

namespace hisnegs::gmf::detail {

BrickCost::BrickCost(const SampleSet& samples, std::size_t brick, std::span<const std::uint32_t> gaussians,
                     double cutoff)
    : samples_(samples),
      first_(samples.brick_begin[brick]),
      count_(samples.brick_begin[brick + 1] - samples.brick_begin[brick]),
      gaussians_(gaussians.size()),
      cutoff_(cutoff) {
  set_num_residuals(static_cast<int>(count_));
  auto* sizes = mutable_parameter_block_sizes();
  for (std::size_t g = 0; g < gaussians_; ++g) {
    for (int b = 0; b < kBlocksPerGaussian; ++b) sizes->push_back(kBlockSizes[b]);
  }
}

bool BrickCost::Evaluate(double const* const* parameters, double* residuals, double** jacobians) const {
  // Per-Gaussian frames (thread_local scratch: Ceres evaluates blocks in parallel).
  thread_local std::vector<GaussianFrame<double>> frames;
  frames.resize(gaussians_);
  for (std::size_t g = 0; g < gaussians_; ++g) {
    const double* const* p = parameters + kBlocksPerGaussian * g;
    prepare_gaussian(p[0], p[1], p[2], p[3][0], frames[g]);
  }
  if (jacobians) {
    for (std::size_t g = 0; g < gaussians_; ++g) {
      for (int b = 0; b < kBlocksPerGaussian; ++b) {
        double* J = jacobians[kBlocksPerGaussian * g + b];
        if (J) std::fill(J, J + static_cast<std::size_t>(count_) * kBlockSizes[b], 0.0);
      }
    }
  }
  double grad[kGaussianParamCount];
  for (std::uint32_t j = 0; j < count_; ++j) {
    const std::size_t s = first_ + j;
    const double x[3] = {samples_.x[s], samples_.y[s], samples_.z[s]};
    const double w = samples_.weight[s];
    double f = 0;
    for (std::size_t g = 0; g < gaussians_; ++g) {
      double z[3];
      if (mahalanobis(frames[g], x, z) > cutoff_) continue;  // outside the support: contributes nothing
      if (!jacobians) {
        f += evaluate_gaussian<double>(frames[g], x, nullptr);
        continue;
      }
      f += evaluate_gaussian(frames[g], x, grad);
      // Block b of Gaussian g covers parameters [offset, offset + size) in GaussianParam order.
      int offset = 0;
      for (int b = 0; b < kBlocksPerGaussian; ++b) {
        double* J = jacobians[kBlocksPerGaussian * g + b];
        if (J) {
          for (int c = 0; c < kBlockSizes[b]; ++c) J[j * kBlockSizes[b] + c] = w * grad[offset + c];
        }
        offset += kBlockSizes[b];
      }
    }
    residuals[j] = w * (f - samples_.value[s]);
  }
  return true;
}

}  // namespace hisnegs::gmf::detail
