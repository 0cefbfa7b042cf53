// SPDX-License-Identifier: Apache-2.0
// The hot loop of the stage-1 objective (gmf/objective.cpp): at one sample, the
// Mahalanobis distance, local coordinates and e^{−m/2} of every candidate Gaussian
// of its block at once, SIMD across candidates (Highway, dispatched at run time).
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "gmf/core/gaussian_math.hpp"
#include "gmf/samples.hpp"

namespace hisnegs::gmf::detail {

inline constexpr std::size_t kCandidateAlign = 32;  // ≥ the widest SIMD vector of doubles on any target

// A block's candidate Gaussians, structure of arrays: field f of candidate i at
// data[f * stride + i]. Fields: the mean (3), then A = diag(1/s) Rᵀ row-major (9),
// so that z = A (x − μ) and m = |z|². stride is a multiple of every SIMD width;
// the padding holds zeros.
struct CandidatePack {
  static constexpr int kFields = 12;
  std::vector<double> data;
  std::size_t size = 0, stride = 0;

  void resize(std::size_t n);  // zero-filled
  // The fields of candidates ids[0..n) from their rows (kGaussianRow doubles each).
  void assign(const double* rows, const std::uint32_t* ids, std::size_t n);
  double* field(int f) { return data.data() + static_cast<std::size_t>(f) * stride; }
  [[nodiscard]] const double* field(int f) const { return data.data() + static_cast<std::size_t>(f) * stride; }
};

// Each Gaussian's candidate fields in one row of kGaussianRow doubles: the
// CandidatePack fields, then 1 / its smallest σ (how fast √m can change along a
// unit step), then padding.
inline constexpr std::size_t kGaussianRow = 16;
inline constexpr std::size_t kRowMaxInvScale = CandidatePack::kFields;

// Writes the row of the Gaussian with frame f.
inline void write_candidate_row(const GaussianFrame<double>& f, double* row) {
  for (int i = 0; i < 3; ++i) {
    row[i] = f.mean[i];
    for (int j = 0; j < 3; ++j) row[3 + 3 * i + j] = f.R[3 * j + i] * f.inv_scale[i];
  }
  row[kRowMaxInvScale] = std::max({f.inv_scale[0], f.inv_scale[1], f.inv_scale[2]});
}

// The ball holding samples [s0, s1) (s1 > s0) of `samples`: {centre x, y, z (their
// mean), radius (the largest distance from it, grown by a relative 1e-9 so that
// every sample is inside despite rounding)}.
inline std::array<double, 4> sample_ball(const SampleSet& samples, std::uint32_t s0, std::uint32_t s1) {
  std::array<double, 4> ball = {0, 0, 0, 0};
  for (std::uint32_t s = s0; s < s1; ++s) {
    ball[0] += samples.x[s];
    ball[1] += samples.y[s];
    ball[2] += samples.z[s];
  }
  for (int a = 0; a < 3; ++a) ball[a] /= static_cast<double>(s1 - s0);
  double radius2 = 0;
  for (std::uint32_t s = s0; s < s1; ++s) {
    const double d[3] = {samples.x[s] - ball[0], samples.y[s] - ball[1], samples.z[s] - ball[2]};
    radius2 = std::max(radius2, d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  }
  ball[3] = std::sqrt(radius2) * (1 + 1e-9);
  return ball;
}

// A lower bound of √m over `ball` for the Gaussian with frame f (scalar; the
// bound candidate_slack computes, without the margin): √m at the centre minus
// 1/σ_min × the radius (√m is the norm of diag(1/s) Rᵀ (x − μ)).
inline double sqrt_mahalanobis_lower_bound(const GaussianFrame<double>& f, const std::array<double, 4>& ball) {
  double z[3];
  const double m = mahalanobis(f, ball.data(), z);
  return std::sqrt(m) - std::max({f.inv_scale[0], f.inv_scale[1], f.inv_scale[2]}) * ball[3];
}

// For the n candidates whose rows start at rows + offset[i] (offset holds n
// rounded up to a multiple of kCandidateAlign valid offsets): slack[i] =
// √m(centre) − max_inv_scale · radius − reach, a lower bound of √m − reach over
// the ball of `radius` about `centre`. slack holds the rounded-up count.
void candidate_slack(const double* rows, const std::int64_t* offset, std::size_t n, const double centre[3],
                     double radius, double reach, double* slack);

// Per candidate i < pack.size (and the padding up to pack.stride): m[i], e[i] =
// e^{−m[i]/2} and z[c * stride + i] (c = 0, 1, 2) at the point x. Each output holds
// pack.stride values (z: 3 × stride).
void candidate_distances(const CandidatePack& pack, const double x[3], double* m, double* e, double* z);

// out[i] = e^{scale (v[i] − shift)} for i < n (n ≤ the capacity of v and out, which
// must hold n rounded up to a multiple of kCandidateAlign).
void shifted_exp(const double* v, std::size_t n, double scale, double shift, double* out);

}  // namespace hisnegs::gmf::detail
