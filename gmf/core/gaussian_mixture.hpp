// SPDX-License-Identifier: Apache-2.0
// The Gaussian mixture itself: per-Gaussian parameters as CONVENTIONS "Gaussians"
// defines them, the container, the closed-form helpers (sigmoid, scales, R(q), Σ),
// a brute-force reference evaluator and summary statistics. No file formats
// (gmf/core/checkpoint.hpp), no fitting, no rendering.
#pragma once

#include <Eigen/Core>
#include <array>
#include <cmath>
#include <concepts>
#include <cstddef>
#include <span>
#include <stdexcept>
#include <string>
#include <string_view>
#include <type_traits>
#include <vector>

#include "gmf/core/gaussian_math.hpp"

namespace hisnegs::gmf {

// One Gaussian, world units (CONVENTIONS "Gaussians", report Eq. 1):
// centre μ = mean, s = exp(log_scale), q = rotation = (w, x, y, z) normalized
// before use (need not be unit, must not be zero), a = sigmoid(intensity_logit).
// Trivially copyable, 11 packed floats in checkpoint property order (also used
// by the CUDA back end). Defaults: a unit Gaussian at the origin, a = 0.5.
struct GaussianParams {
  std::array<float, 3> mean{0.0f, 0.0f, 0.0f};
  std::array<float, 3> log_scale{0.0f, 0.0f, 0.0f};
  std::array<float, 4> rotation{1.0f, 0.0f, 0.0f, 0.0f};  // w x y z
  float intensity_logit = 0.0f;
};
static_assert(std::is_trivially_copyable_v<GaussianParams> && std::is_standard_layout_v<GaussianParams>);
static_assert(sizeof(GaussianParams) == kGaussianParamCount * sizeof(float), "GaussianParams must be 11 packed floats");

// Names of the 11 parameters in memory order; they are also the checkpoint's
// PLY property names (scale_i hold log-scales, rot_0 is w).
inline constexpr std::array<std::string_view, kGaussianParamCount> kGaussianParamNames = {
    "x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "intensity_logit"};

// The parameters as an array in kGaussianParamNames order, and back.
[[nodiscard]] std::array<float, kGaussianParamCount> to_array(const GaussianParams& g);
[[nodiscard]] GaussianParams from_array(const std::array<float, kGaussianParamCount>& values);

// K Gaussians, contiguous (data() can be copied to a device as K × 44 bytes).
class GaussianMixture {
 public:
  using value_type = GaussianParams;
  using iterator = std::vector<GaussianParams>::iterator;
  using const_iterator = std::vector<GaussianParams>::const_iterator;

  GaussianMixture() = default;
  explicit GaussianMixture(std::vector<GaussianParams> gaussians) : gaussians_(std::move(gaussians)) {}

  [[nodiscard]] std::size_t size() const { return gaussians_.size(); }
  [[nodiscard]] bool empty() const { return gaussians_.empty(); }
  void reserve(std::size_t n) { gaussians_.reserve(n); }
  void push_back(const GaussianParams& g) { gaussians_.push_back(g); }
  // New Gaussians are default GaussianParams.
  void resize(std::size_t n) { gaussians_.resize(n); }
  void clear() { gaussians_.clear(); }

  [[nodiscard]] const GaussianParams& operator[](std::size_t k) const { return gaussians_[k]; }
  [[nodiscard]] GaussianParams& operator[](std::size_t k) { return gaussians_[k]; }
  [[nodiscard]] const GaussianParams* data() const { return gaussians_.data(); }
  [[nodiscard]] GaussianParams* data() { return gaussians_.data(); }
  [[nodiscard]] std::span<const GaussianParams> params() const { return gaussians_; }
  [[nodiscard]] std::span<GaussianParams> params() { return gaussians_; }

  [[nodiscard]] const_iterator begin() const { return gaussians_.begin(); }
  [[nodiscard]] const_iterator end() const { return gaussians_.end(); }
  [[nodiscard]] iterator begin() { return gaussians_.begin(); }
  [[nodiscard]] iterator end() { return gaussians_.end(); }

 private:
  std::vector<GaussianParams> gaussians_;
};

// ----- closed-form helpers (T = float or double), on gaussian_math.hpp's ops -----

// Peak intensity a = sigmoid(intensity_logit).
template <std::floating_point T = double>
[[nodiscard]] inline T intensity(const GaussianParams& g) {
  return sigmoid(static_cast<T>(g.intensity_logit));
}

// Standard deviations along the Gaussian's own axes, s = exp(log_scale), world units.
template <std::floating_point T = double>
[[nodiscard]] inline Eigen::Matrix<T, 3, 1> scales(const GaussianParams& g) {
  return {std::exp(static_cast<T>(g.log_scale[0])), std::exp(static_cast<T>(g.log_scale[1])),
          std::exp(static_cast<T>(g.log_scale[2]))};
}

// q / |q| as (w, x, y, z). Throws std::invalid_argument for q = 0 (which a
// checkpoint can never hold) or a non-finite q.
template <std::floating_point T = double>
[[nodiscard]] inline Eigen::Matrix<T, 4, 1> normalized_quaternion(const Eigen::Matrix<T, 4, 1>& q_wxyz) {
  const T norm = q_wxyz.norm();
  if (!(norm > T(0)) || !std::isfinite(norm)) {
    throw std::invalid_argument("quaternion (w, x, y, z) has no direction: its norm is zero or not finite");
  }
  return q_wxyz / norm;
}
template <std::floating_point T = double>
[[nodiscard]] inline Eigen::Matrix<T, 4, 1> normalized_quaternion(const GaussianParams& g) {
  return normalized_quaternion<T>(Eigen::Matrix<T, 4, 1>(g.rotation[0], g.rotation[1], g.rotation[2], g.rotation[3]));
}

// R(q) for q = (w, x, y, z), normalized here first (throws like
// normalized_quaternion). Columns are the Gaussian's axes in world coordinates.
template <std::floating_point T = double>
[[nodiscard]] inline Eigen::Matrix<T, 3, 3> rotation_matrix(const Eigen::Matrix<T, 4, 1>& q_wxyz) {
  const Eigen::Matrix<T, 4, 1> q = normalized_quaternion<T>(q_wxyz);
  Eigen::Matrix<T, 3, 3, Eigen::RowMajor> r;
  quat_to_rotmat(q.data(), r.data());
  return r;
}
template <std::floating_point T = double>
[[nodiscard]] inline Eigen::Matrix<T, 3, 3> rotation_matrix(const GaussianParams& g) {
  return rotation_matrix<T>(Eigen::Matrix<T, 4, 1>(g.rotation[0], g.rotation[1], g.rotation[2], g.rotation[3]));
}

// Σ = R(q) diag(s²) R(q)ᵀ = M Mᵀ with M = R diag(s), world units² (covariance_from_axes).
// Positive definite for finite parameters and exactly symmetric.
template <std::floating_point T = double>
[[nodiscard]] inline Eigen::Matrix<T, 3, 3> covariance(const GaussianParams& g) {
  const Eigen::Matrix<T, 3, 3, Eigen::RowMajor> r = rotation_matrix<T>(g);
  const Eigen::Matrix<T, 3, 1> s = scales<T>(g);
  Eigen::Matrix<T, 3, 3, Eigen::RowMajor> sigma;
  covariance_from_axes(r.data(), s.data(), sigma.data());
  return sigma;
}

// f(x) = Σ_k a_k exp(-½ (x-μ_k)ᵀ Σ_k⁻¹ (x-μ_k)) at world point x (report Eq. 1),
// brute force over all K Gaussians in double precision. The reference the fast
// evaluators are tested against; O(K) per call. 0 for an empty mixture.
// Throws std::invalid_argument if a Gaussian has a zero quaternion.
[[nodiscard]] double evaluate_mixture(const GaussianMixture& mixture, const Eigen::Vector3d& x_world);
// The same counting only the terms with m_k = (x-μ_k)ᵀ Σ_k⁻¹ (x-μ_k) <= support (δ):
// the sum a fit with gmf.mahalanobis_cutoff = δ fits and the renderer draws.
[[nodiscard]] double evaluate_mixture(const GaussianMixture& mixture, const Eigen::Vector3d& x_world, double support);

// ----- summary statistics (`hisnegs info`) -----

struct ParamRange {
  double min = 0.0;
  double max = 0.0;
  double mean = 0.0;
};

// All fields are 0 for an empty mixture.
struct MixtureStats {
  std::size_t count = 0;
  // Raw stored values, one entry per parameter in kGaussianParamNames order
  // (so scale_i are log-scales and rot_i unnormalized quaternion components).
  std::array<ParamRange, kGaussianParamCount> params{};
  std::array<double, 3> mean_scale{};  // mean of s = exp(log_scale) per axis, world units
  double intensity_min = 0.0;          // min of a = sigmoid(intensity_logit)
  double intensity_max = 0.0;
  double intensity_mean = 0.0;
  // Needles: Gaussians whose longest axis is more than kNeedleAxisRatio
  // times their shortest (long thin shapes radiating from a neuron fitted on noise).
  std::size_t needles = 0;
  double largest_axis_ratio = 0.0;
};

// The axis ratio above which a Gaussian counts as a needle (MixtureStats::needles).
inline constexpr double kNeedleAxisRatio = 20.0;

[[nodiscard]] MixtureStats compute_stats(const GaussianMixture& mixture);

// The name of the parameter group (param_layout.hpp) of flat index i: "means",
// "log-scales", "rotation" or "intensity".
[[nodiscard]] std::string_view parameter_group(std::size_t i);

// "" if every value of a flat per-Gaussian array (parameters or their gradient,
// kGaussianParamCount per Gaussian) is finite, else where the first non-finite one is:
// "the rotation gradient of Gaussian 12 (nan)" for what = "gradient".
template <class T>
[[nodiscard]] std::string describe_non_finite(std::span<const T> values, std::string_view what) {
  for (std::size_t i = 0; i < values.size(); ++i) {
    if (std::isfinite(values[i])) continue;
    return "the " + std::string(parameter_group(i)) + " " + std::string(what) + " of Gaussian " +
           std::to_string(i / kGaussianParamCount) + " (" +
           (std::isnan(values[i]) ? "nan"
            : values[i] > 0       ? "+inf"
                                  : "-inf") +
           ")";
  }
  return {};
}

// The mixture's parameters as one flat array (K × kGaussianParamCount floats in
// GaussianParam order), viewing the mixture's own storage; and a mixture from such
// an array (its size must be a multiple of kGaussianParamCount, else std::invalid_argument).
[[nodiscard]] std::span<const float> flat_params(const GaussianMixture& mixture);
[[nodiscard]] std::span<float> flat_params(GaussianMixture& mixture);
[[nodiscard]] GaussianMixture mixture_from_flat(std::span<const float> params);

// The double-precision evaluation frame (gaussian_math.hpp) of a stored Gaussian.
[[nodiscard]] inline GaussianFrame<double> frame_of(const GaussianParams& p) {
  const double mean[3] = {p.mean[0], p.mean[1], p.mean[2]};
  const double log_scale[3] = {p.log_scale[0], p.log_scale[1], p.log_scale[2]};
  const double q[4] = {p.rotation[0], p.rotation[1], p.rotation[2], p.rotation[3]};
  GaussianFrame<double> f;
  prepare_gaussian(mean, log_scale, q, static_cast<double>(p.intensity_logit), f);
  return f;
}

}  // namespace hisnegs::gmf
