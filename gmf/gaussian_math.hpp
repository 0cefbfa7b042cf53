// One anisotropic Gaussian's value and its exact derivatives with respect to its
// 11 parameters (CONVENTIONS "Gaussians"): g(x) = a exp(-½ m), m = Σ_i (u_i / s_i)²,
// u = R(q̂)ᵀ (x − μ), s = exp(log_scale), q̂ = q / |q|, a = sigmoid(logit).
// Templated on the scalar, __host__ __device__, no allocation: the Ceres cost
// functions (double), the CPU splatting back end and CUDA all use this one header.
#pragma once

#include <cmath>

#include "splat/hd.hpp"

namespace hisnegs::gmf {

// Parameter order of every gradient here (== PLY property order).
enum GaussianParam : int {
  kMeanX = 0, kMeanY, kMeanZ,
  kLogScale0, kLogScale1, kLogScale2,
  kRotW, kRotX, kRotY, kRotZ,
  kLogit,
  kNumGaussianParams
};

// Quantities of one Gaussian that do not depend on x.
template <class T>
struct GaussianFrame {
  T mean[3];
  T R[9];          // R(q̂), row-major: columns are the principal axes in world space
  T inv_scale[3];  // 1 / s_i
  T q_hat[4];      // normalized quaternion (w, x, y, z)
  T inv_q_norm;    // 1 / |q|
  T a;             // intensity sigmoid(logit)
};

// Rotation matrix of a unit quaternion (w, x, y, z), row-major.
template <class T>
HISNEGS_HD void quaternion_to_rotation(const T q[4], T R[9]) {
  const T w = q[0], x = q[1], y = q[2], z = q[3];
  R[0] = T(1) - T(2) * (y * y + z * z);
  R[1] = T(2) * (x * y - w * z);
  R[2] = T(2) * (x * z + w * y);
  R[3] = T(2) * (x * y + w * z);
  R[4] = T(1) - T(2) * (x * x + z * z);
  R[5] = T(2) * (y * z - w * x);
  R[6] = T(2) * (x * z - w * y);
  R[7] = T(2) * (y * z + w * x);
  R[8] = T(1) - T(2) * (x * x + y * y);
}

// Precomputes the x-independent part. `q` need not be unit length (it must not be 0).
template <class T>
HISNEGS_HD void prepare_gaussian(const T mean[3], const T log_scale[3], const T q[4], T logit, GaussianFrame<T>& f) {
  using std::exp;
  using std::sqrt;
  for (int i = 0; i < 3; ++i) {
    f.mean[i] = mean[i];
    f.inv_scale[i] = exp(-log_scale[i]);
  }
  const T norm = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  f.inv_q_norm = T(1) / norm;
  for (int i = 0; i < 4; ++i) f.q_hat[i] = q[i] * f.inv_q_norm;
  quaternion_to_rotation(f.q_hat, f.R);
  // sigmoid without overflow for large |logit|
  f.a = logit >= T(0) ? T(1) / (T(1) + exp(-logit)) : exp(logit) / (T(1) + exp(logit));
}

// Squared Mahalanobis distance m of x, and the local coordinates scaled by 1/s (z).
template <class T>
HISNEGS_HD T mahalanobis(const GaussianFrame<T>& f, const T x[3], T z[3]) {
  const T d0 = x[0] - f.mean[0], d1 = x[1] - f.mean[1], d2 = x[2] - f.mean[2];
  T m(0.0);
  for (int i = 0; i < 3; ++i) {
    // u_i = (Rᵀ d)_i = column i of R dotted with d
    const T u = f.R[i] * d0 + f.R[3 + i] * d1 + f.R[6 + i] * d2;
    z[i] = u * f.inv_scale[i];
    m += z[i] * z[i];
  }
  return m;
}

// g(x) = a exp(-m/2). When `grad` is not null it receives ∂g/∂θ for the 11
// parameters θ in GaussianParam order:
//   ∂g/∂μ        = g Σ⁻¹ d = g R (z / s)
//   ∂g/∂log s_i  = g z_i²
//   ∂g/∂q        = -½ g (I − q̂ q̂ᵀ)/|q| · ∂m/∂q̂,  ∂m/∂q̂_k = Σ_ab (d wᵀ)_ab ∂R_ab/∂q̂_k,  w = 2 z / s
//   ∂g/∂logit    = g (1 − a)
template <class T>
HISNEGS_HD T evaluate_gaussian(const GaussianFrame<T>& f, const T x[3], T* grad) {
  using std::exp;
  T z[3];
  const T m = mahalanobis(f, x, z);
  const T g = f.a * exp(T(-0.5) * m);
  if (!grad) return g;
  const T d[3] = {x[0] - f.mean[0], x[1] - f.mean[1], x[2] - f.mean[2]};
  T zs[3];  // z / s  (= Σ⁻¹-weighted local coordinates)
  for (int i = 0; i < 3; ++i) zs[i] = z[i] * f.inv_scale[i];
  for (int r = 0; r < 3; ++r) grad[kMeanX + r] = g * (f.R[3 * r] * zs[0] + f.R[3 * r + 1] * zs[1] + f.R[3 * r + 2] * zs[2]);
  for (int i = 0; i < 3; ++i) grad[kLogScale0 + i] = g * z[i] * z[i];
  // G = d wᵀ with w = 2 z / s = ∂m/∂u; ∂m/∂R_ab = G_ab.
  T G[9];
  for (int a = 0; a < 3; ++a)
    for (int b = 0; b < 3; ++b) G[3 * a + b] = d[a] * T(2) * zs[b];
  const T w = f.q_hat[0], qx = f.q_hat[1], qy = f.q_hat[2], qz = f.q_hat[3];
  // Σ_ab G_ab ∂R_ab/∂q̂_k for k = w, x, y, z (derivatives of quaternion_to_rotation).
  T dm_dqhat[4];
  dm_dqhat[0] = T(2) * (-qz * G[1] + qy * G[2] + qz * G[3] - qx * G[5] - qy * G[6] + qx * G[7]);
  dm_dqhat[1] = T(2) * (qy * G[1] + qz * G[2] + qy * G[3] - T(2) * qx * G[4] - w * G[5] + qz * G[6] + w * G[7] - T(2) * qx * G[8]);
  dm_dqhat[2] = T(2) * (T(-2) * qy * G[0] + qx * G[1] + w * G[2] + qx * G[3] + qz * G[5] - w * G[6] + qz * G[7] - T(2) * qy * G[8]);
  dm_dqhat[3] = T(2) * (T(-2) * qz * G[0] - w * G[1] + qx * G[2] + w * G[3] - T(2) * qz * G[4] + qy * G[5] + qx * G[6] + qy * G[7]);
  // Through q̂ = q / |q|: project out the radial part.
  const T radial = dm_dqhat[0] * w + dm_dqhat[1] * qx + dm_dqhat[2] * qy + dm_dqhat[3] * qz;
  for (int k = 0; k < 4; ++k) grad[kRotW + k] = T(-0.5) * g * (dm_dqhat[k] - radial * f.q_hat[k]) * f.inv_q_norm;
  grad[kLogit] = g * (T(1) - f.a);
  return g;
}

// Half-extents of the axis-aligned box holding {x : m(x) <= cutoff}: sqrt(cutoff Σ_ii).
template <class T>
HISNEGS_HD void support_half_extents(const GaussianFrame<T>& f, T cutoff, T half[3]) {
  using std::sqrt;
  for (int r = 0; r < 3; ++r) {
    T var(0.0);
    for (int i = 0; i < 3; ++i) {
      const T s = T(1) / f.inv_scale[i];
      var += f.R[3 * r + i] * f.R[3 * r + i] * s * s;
    }
    half[r] = sqrt(cutoff * var);
  }
}

}  // namespace hisnegs::gmf
