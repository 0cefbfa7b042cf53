// SPDX-License-Identifier: Apache-2.0
// The math of one anisotropic Gaussian (CONVENTIONS "Gaussians", report Eq. 1),
// g(x) = a exp(-½ m), m = Σ_i (u_i / s_i)², u = R(q̂)ᵀ (x − μ), s = exp(log_scale),
// q̂ = q / |q|, a = sigmoid(logit), as small forward ops, each beside its
// vector-Jacobian product (VJP): given dL/d(output), the VJP writes dL/d(inputs).
// Templated on the scalar (float, double, ceres::Jet), __host__ __device__, no
// allocation: the Ceres fit, the CPU and CUDA splatting back ends and every
// reference use these ops and nothing else for R(q), Σ, sigmoid and m.
#pragma once

#include <cmath>

#include "gmf/core/hd.hpp"
#include "gmf/core/param_layout.hpp"

namespace hisnegs::gmf {

// ----- intensity: a = sigmoid(ℓ) -----

// 1 / (1 + e^-ℓ) without overflow for any finite ℓ (exp only of a non-positive number).
template <class T>
HISNEGS_HD T sigmoid(T logit) {
  using std::exp;
  return logit >= T(0) ? T(1) / (T(1) + exp(-logit)) : exp(logit) / (T(1) + exp(logit));
}
// ℓ = logit(a) = ln(a / (1 − a)), sigmoid's inverse, for a in (0, 1).
template <class T>
HISNEGS_HD T logit(T a) {
  using std::log;
  return log(a / (T(1) - a));
}
// dL/dℓ from a = sigmoid(ℓ) and dL/da.
template <class T>
HISNEGS_HD T sigmoid_vjp(T a, T dL_da) {
  return dL_da * a * (T(1) - a);
}

// ----- q̂ = q / |q| -----

// Writes q̂ = q / |q| (w, x, y, z) and returns 1 / |q|. q must not be 0.
template <class T>
HISNEGS_HD T quat_normalize(const T q[4], T q_hat[4]) {
  using std::sqrt;
  T inv_norm = T(1) / sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);  // not const: returned (moved for a Jet)
  for (int i = 0; i < 4; ++i) q_hat[i] = q[i] * inv_norm;
  return inv_norm;
}
// dL/dq = (dL/dq̂ − q̂ (q̂ · dL/dq̂)) / |q|: the radial part of dL/dq̂ is projected out.
template <class T>
HISNEGS_HD void quat_normalize_vjp(const T q_hat[4], T inv_norm, const T dL_dq_hat[4], T dL_dq[4]) {
  const T radial =
      q_hat[0] * dL_dq_hat[0] + q_hat[1] * dL_dq_hat[1] + q_hat[2] * dL_dq_hat[2] + q_hat[3] * dL_dq_hat[3];
  for (int k = 0; k < 4; ++k) dL_dq[k] = (dL_dq_hat[k] - radial * q_hat[k]) * inv_norm;
}

// ----- R(q̂) -----

// Rotation matrix of a unit quaternion (w, x, y, z), row-major: its columns are the
// Gaussian's principal axes in world coordinates.
template <class T>
HISNEGS_HD void quat_to_rotmat(const T q[4], T R[9]) {
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
// dL/dq_k = Σ_ab dL/dR_ab ∂R_ab/∂q_k of the polynomial quat_to_rotmat (q taken as
// given: chain through quat_normalize_vjp for a raw quaternion).
template <class T>
HISNEGS_HD void quat_to_rotmat_vjp(const T q[4], const T dR[9], T dL_dq[4]) {
  const T w = q[0], x = q[1], y = q[2], z = q[3];
  dL_dq[0] = T(2) * (-z * dR[1] + y * dR[2] + z * dR[3] - x * dR[5] - y * dR[6] + x * dR[7]);
  dL_dq[1] = T(2) * (y * dR[1] + z * dR[2] + y * dR[3] - T(2) * x * dR[4] - w * dR[5] + z * dR[6] + w * dR[7] -
                     T(2) * x * dR[8]);
  dL_dq[2] = T(2) * (T(-2) * y * dR[0] + x * dR[1] + w * dR[2] + x * dR[3] + z * dR[5] - w * dR[6] + z * dR[7] -
                     T(2) * y * dR[8]);
  dL_dq[3] = T(2) * (T(-2) * z * dR[0] - w * dR[1] + x * dR[2] + w * dR[3] - T(2) * z * dR[4] + y * dR[5] + x * dR[6] +
                     y * dR[7]);
}

// ----- Σ = M Mᵀ, M = R diag(s) -----

// The covariance of axes R (row-major) and standard deviations s, row-major and
// exactly symmetric (each entry is one dot product of two rows of M, which
// commutes in IEEE arithmetic).
template <class T>
HISNEGS_HD void covariance_from_axes(const T R[9], const T s[3], T cov[9]) {
  T M[9];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) M[3 * r + c] = R[3 * r + c] * s[c];
  }
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      cov[3 * r + c] = M[3 * r + 0] * M[3 * c + 0] + M[3 * r + 1] * M[3 * c + 1] + M[3 * r + 2] * M[3 * c + 2];
    }
  }
}
// dL/dR and dL/ds from a SYMMETRIC dL/dΣ: dL/dM = 2 (dL/dΣ) M, then
// dL/dR_rc = dL/dM_rc s_c and dL/ds_c = Σ_r dL/dM_rc R_rc.
template <class T>
HISNEGS_HD void covariance_from_axes_vjp(const T R[9], const T s[3], const T dL_dcov[9], T dL_dR[9], T dL_ds[3]) {
  T M[9];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) M[3 * r + c] = R[3 * r + c] * s[c];
  }
  T dM[9];
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      dM[3 * r + c] = T(2) * (dL_dcov[3 * r] * M[c] + dL_dcov[3 * r + 1] * M[3 + c] + dL_dcov[3 * r + 2] * M[6 + c]);
    }
  }
  for (int c = 0; c < 3; ++c) {
    T ds = T(0);
    for (int r = 0; r < 3; ++r) {
      ds += dM[3 * r + c] * R[3 * r + c];
      dL_dR[3 * r + c] = dM[3 * r + c] * s[c];
    }
    dL_ds[c] = ds;
  }
}

// ----- one Gaussian's frame and its Mahalanobis distance -----

// Quantities of one Gaussian that do not depend on x.
template <class T>
struct GaussianFrame {
  T mean[3];
  T R[9];          // R(q̂), row-major: columns are the principal axes in world space
  T scale[3];      // s_i = exp(log_scale_i)
  T inv_scale[3];  // 1 / s_i
  T q_hat[4];      // normalized quaternion (w, x, y, z)
  T inv_q_norm;    // 1 / |q|
  T a;             // intensity sigmoid(logit)
};

// Precomputes the x-independent part. `q` need not be unit length (it must not be 0).
template <class T>
HISNEGS_HD void prepare_gaussian(const T mean[3], const T log_scale[3], const T q[4], T logit, GaussianFrame<T>& f) {
  using std::exp;
  for (int i = 0; i < 3; ++i) {
    f.mean[i] = mean[i];
    f.scale[i] = exp(log_scale[i]);
    f.inv_scale[i] = exp(-log_scale[i]);
  }
  f.inv_q_norm = quat_normalize(q, f.q_hat);
  quat_to_rotmat(f.q_hat, f.R);
  f.a = sigmoid(logit);
}
// The same from the kGaussianParamCount parameters in GaussianParam order.
template <class T>
HISNEGS_HD void prepare_gaussian(const T p[kGaussianParamCount], GaussianFrame<T>& f) {
  prepare_gaussian(&p[kMeanX], &p[kLogScale0], &p[kRotW], p[kLogit], f);
}

// dL/dq (raw quaternion) from dL/dR(q̂): quat_to_rotmat_vjp, then quat_normalize_vjp.
template <class T>
HISNEGS_HD void rotation_vjp(const GaussianFrame<T>& f, const T dL_dR[9], T dL_dq[4]) {
  T dL_dq_hat[4];
  quat_to_rotmat_vjp(f.q_hat, dL_dR, dL_dq_hat);
  quat_normalize_vjp(f.q_hat, f.inv_q_norm, dL_dq_hat, dL_dq);
}

// Σ of the frame (world units²).
template <class T>
HISNEGS_HD void world_covariance(const GaussianFrame<T>& f, T cov[9]) {
  covariance_from_axes(f.R, f.scale, cov);
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
// From dL/dm at x (z as mahalanobis() returned it): dL/dμ = −2 dL/dm R (z / s),
// dL/dR = dL/dm d (2 z / s)ᵀ with d = x − μ, dL/dlog s_i = −2 dL/dm z_i².
template <class T>
HISNEGS_HD void mahalanobis_vjp(const GaussianFrame<T>& f, const T x[3], const T z[3], T dL_dm, T dL_dmean[3],
                                T dL_dR[9], T dL_dlog_scale[3]) {
  const T d[3] = {x[0] - f.mean[0], x[1] - f.mean[1], x[2] - f.mean[2]};
  T zs[3];  // z / s: Σ⁻¹-weighted local coordinates
  for (int i = 0; i < 3; ++i) zs[i] = z[i] * f.inv_scale[i];
  const T k = T(-2) * dL_dm;
  for (int r = 0; r < 3; ++r) {
    dL_dmean[r] = k * (f.R[3 * r] * zs[0] + f.R[3 * r + 1] * zs[1] + f.R[3 * r + 2] * zs[2]);
  }
  for (int i = 0; i < 3; ++i) dL_dlog_scale[i] = k * z[i] * z[i];
  for (int a = 0; a < 3; ++a) {
    for (int b = 0; b < 3; ++b) dL_dR[3 * a + b] = dL_dm * d[a] * T(2) * zs[b];
  }
}

// g(x) = a exp(-m/2). When `grad` is not null it receives ∂g/∂θ for the
// kGaussianParamCount parameters θ in GaussianParam order, through the VJPs above
// with dL/dg = 1: dg/dm = −g/2, dg/da = exp(−m/2).
template <class T>
HISNEGS_HD T evaluate_gaussian(const GaussianFrame<T>& f, const T x[3], T* grad) {
  using std::exp;
  T z[3];
  const T m = mahalanobis(f, x, z);
  const T e = exp(T(-0.5) * m);
  T g = f.a * e;  // not const: returned (moved for a Jet)
  if (!grad) return g;
  T dL_dR[9];
  mahalanobis_vjp(f, x, z, T(-0.5) * g, &grad[kMeanX], dL_dR, &grad[kLogScale0]);
  rotation_vjp(f, dL_dR, &grad[kRotW]);
  grad[kLogit] = sigmoid_vjp(f.a, e);
  return g;
}

// Half-extents of the axis-aligned box holding {x : m(x) <= cutoff}: sqrt(cutoff Σ_ii).
template <class T>
HISNEGS_HD void support_half_extents(const GaussianFrame<T>& f, T cutoff, T half[3]) {
  using std::sqrt;
  T cov[9];
  world_covariance(f, cov);
  for (int r = 0; r < 3; ++r) half[r] = sqrt(cutoff * cov[4 * r]);
}

}  // namespace hisnegs::gmf
