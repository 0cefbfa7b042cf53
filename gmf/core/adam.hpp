// SPDX-License-Identifier: Apache-2.0
// Adam (Kingma & Ba 2015) over a flat array of Gaussians' parameters, one learning
// rate per parameter group (param_layout.hpp), with its state (step count, first
// and second moments) kept per Gaussian so density control can reset, append and
// drop Gaussians, and written to / read from a binary record. Used by the stage-1
// fit and the stage-2 trainer alike. Knows no loss.
#pragma once

#include <array>
#include <cmath>
#include <cstdint>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "gmf/core/density_ops.hpp"
#include "gmf/core/param_layout.hpp"
#include "io/binary_io.hpp"

namespace hisnegs::gmf {

struct AdamOptions {
  double beta1 = 0.9;     // first-moment decay, [0, 1)
  double beta2 = 0.999;   // second-moment decay, [0, 1)
  double epsilon = 1e-8;  // added to √v̂, > 0
};

// Learning rate of each parameter group, indexed by ParamGroup.
using GroupRates = std::array<double, kParamGroupCount>;

// T is the storage of the parameters and moments (float for the trainer, double for
// the fit); every update is computed in double and rounded once.
template <class T>
class Adam {
 public:
  explicit Adam(AdamOptions options = {}, std::size_t gaussians = 0) : options_(options) { resize(gaussians); }

  // One step: θ ← θ − lr_g m̂ / (√v̂ + ε), m̂ = m / (1 − β1^t), v̂ = v / (1 − β2^t), t the
  // 1-based step number, g the group of each parameter. `params` and `grad` hold
  // kGaussianParamCount × gaussians() values.
  void step(std::span<T> params, std::span<const T> grad, const GroupRates& rates) {
    if (params.size() != m_.size() || grad.size() != m_.size()) {
      throw std::invalid_argument("Adam::step: " + std::to_string(params.size()) + " parameters and " +
                                  std::to_string(grad.size()) + " gradients for a state of " +
                                  std::to_string(m_.size()));
    }
    ++steps_;
    const double t = static_cast<double>(steps_);
    const double bc1 = 1.0 - std::pow(options_.beta1, t);
    const double bc2 = 1.0 - std::pow(options_.beta2, t);
    for (std::size_t i = 0; i < params.size(); ++i) {
      const double g = grad[i];
      const double m = options_.beta1 * m_[i] + (1.0 - options_.beta1) * g;
      const double v = options_.beta2 * v_[i] + (1.0 - options_.beta2) * g * g;
      m_[i] = static_cast<T>(m);
      v_[i] = static_cast<T>(v);
      const double lr = rates[group_of(static_cast<int>(i % kGaussianParamCount))];
      params[i] = static_cast<T>(params[i] - lr * (m / bc1) / (std::sqrt(v / bc2) + options_.epsilon));
    }
  }

  [[nodiscard]] std::int64_t steps() const { return steps_; }
  [[nodiscard]] std::size_t gaussians() const { return m_.size() / kGaussianParamCount; }
  [[nodiscard]] std::span<const T> m() const { return m_; }
  [[nodiscard]] std::span<const T> v() const { return v_; }
  [[nodiscard]] const AdamOptions& options() const { return options_; }

  // Gaussians added at the end start with zero moments.
  void resize(std::size_t gaussians) {
    m_.resize(gaussians * kGaussianParamCount, T(0));
    v_.resize(gaussians * kGaussianParamCount, T(0));
  }
  // Gaussian k starts over (e.g. it was replaced by a split child).
  void reset(std::size_t k) {
    std::fill_n(m_.begin() + static_cast<std::ptrdiff_t>(k * kGaussianParamCount), kGaussianParamCount, T(0));
    std::fill_n(v_.begin() + static_cast<std::ptrdiff_t>(k * kGaussianParamCount), kGaussianParamCount, T(0));
  }
  // Keeps the Gaussians `kept` (ascending), in order (keep_rows).
  void keep(std::span<const std::uint32_t> kept) {
    keep_rows(m_, kept, kGaussianParamCount);
    keep_rows(v_, kept, kGaussianParamCount);
  }
  // Forgets the moments and the step count (same Gaussian count).
  void restart() {
    std::fill(m_.begin(), m_.end(), T(0));
    std::fill(v_.begin(), v_.end(), T(0));
    steps_ = 0;
  }

  // The moments as two arrays (m, then v); the step count is the caller's to record.
  void write_moments(io::BinaryWriter& w) const {
    w.put_array(std::span<const T>(m_));
    w.put_array(std::span<const T>(v_));
  }
  // Reads what write_moments wrote for `gaussians` Gaussians and sets the step count.
  // Throws io::InputError (via `r`) for a record of another size or a negative step.
  void read_moments(io::BinaryReader& r, std::int64_t steps, std::size_t gaussians) {
    if (steps < 0) r.fail("negative step count " + std::to_string(steps));
    std::vector<T> m = r.get_array<T>(gaussians * kGaussianParamCount);
    std::vector<T> v = r.get_array<T>(gaussians * kGaussianParamCount);
    m_ = std::move(m);
    v_ = std::move(v);
    steps_ = steps;
  }

 private:
  AdamOptions options_;
  std::vector<T> m_, v_;
  std::int64_t steps_ = 0;
};

}  // namespace hisnegs::gmf
