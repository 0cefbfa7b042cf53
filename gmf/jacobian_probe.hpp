// SPDX-License-Identifier: Apache-2.0
// One residual block of the stage-1 fit with its Jacobian, evaluated the three ways
// Ceres offers (the analytic BlockCost, DynamicNumericDiffCostFunction with central
// differences, DynamicAutoDiffCostFunction with Jets), on a fixed random block:
// what `hisnegs bench gmf` times. Ceres stays in the .cpp.
#pragma once

#include <cstdint>
#include <memory>

namespace hisnegs::gmf {

enum class JacobianMethod { kAnalytic, kNumericCentral, kAutoDiff };

class JacobianProbe {
 public:
  // `samples` random samples in a 0.04-wide cube and `gaussians` random Gaussians
  // over them (seeded, so every method sees the same block).
  JacobianProbe(int samples, int gaussians, JacobianMethod method, std::uint64_t seed = 1);
  ~JacobianProbe();
  JacobianProbe(const JacobianProbe&) = delete;
  JacobianProbe& operator=(const JacobianProbe&) = delete;

  // Residuals and the full Jacobian once; returns the first residual (to keep the
  // work observable).
  double evaluate();
  [[nodiscard]] int residuals() const;
  [[nodiscard]] int parameters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hisnegs::gmf
