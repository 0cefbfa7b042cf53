// SPDX-License-Identifier: Apache-2.0
// Small random splatting scenes and the comparison helpers shared by the splat
// renderer tests (reference, back-end suite, CPU and CUDA specifics). No checks here.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <ostream>
#include <random>
#include <string>
#include <vector>

#include "splat/backend.hpp"
#include "splat/camera.hpp"
#include "splat/splat_renderer.hpp"

namespace hisnegs::splat {

// GoogleTest prints a Backend parameter as "cpu" / "cuda" (found by ADL).
inline void PrintTo(Backend backend, std::ostream* os) { *os << to_string(backend); }

}  // namespace hisnegs::splat

namespace hisnegs::splat::testing {

struct SplatScene {
  std::vector<double> params;  // 11 K
  Intrinsics K;
  CameraView view;
};

// `count` Gaussians with σ in [lo, hi] world units (3-8 pixels at the default
// sizes), random rotations, intensities in [0.3, 0.95], seen from an orbit pose.
inline SplatScene make_splat_scene(int count, std::uint64_t seed, int width = 40, int height = 32, double lo = 0.04,
                                   double hi = 0.12) {
  SplatScene s;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> n(0, 1);
  for (int k = 0; k < count; ++k) {
    s.params.push_back(0.35 * (2 * u(rng) - 1));
    s.params.push_back(0.3 * (2 * u(rng) - 1));
    s.params.push_back(0.2 * (2 * u(rng) - 1));
    for (int a = 0; a < 3; ++a) s.params.push_back(std::log(lo + (hi - lo) * u(rng)));
    double q[4] = {n(rng), n(rng), n(rng), n(rng)};
    const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (double v : q) s.params.push_back(1.3 * v / norm);  // deliberately not unit length
    const double a = 0.3 + 0.65 * u(rng);
    s.params.push_back(std::log(a / (1 - a)));
  }
  s.K.width = width;
  s.K.height = height;
  s.K.fx = s.K.fy = 2.2 * width;
  s.K.cx = 0.5 * width + 0.3;
  s.K.cy = 0.5 * height - 0.2;
  s.view = orbit_view(20.0 + 40 * u(rng), 360.0 * u(rng), 2.5, "test");
  return s;
}

// How far one pixel may move when a term at q ≈ δ (g_b = a e^-8 < 3.4e-4) is in one
// sum and not the other, float and double (or two float back ends) deciding q <= δ
// differently. Hard: only if g_b is the max, by <= g_b. Soft: ΔI = e_b (g_b − I) /
// (S + e_b), e_b = e^{β g_b − m}; if g_b is the max, I <= g_b and |ΔI| <= g_b; else
// with x = g_max − g_b, |ΔI| <= x e^{−βx} <= 1 / (β e) (7.4e-3 at β = 50).
inline double boundary_flip_bound(const SplatSettings& s) {
  const double g_b = std::exp(-0.5 * s.cutoff);
  return s.mode == MipMode::kMax ? g_b : std::max(g_b, 1.0 / (s.beta * std::exp(1.0)));
}

inline std::vector<float> to_float(const std::vector<double>& v) { return {v.begin(), v.end()}; }

// A few bright Gaussians over many dim ones (σ 6-18 pixels, 64 x 48) so that the
// soft-MIP skip rule drops terms: 6 of 60 with a = sigmoid(3), the rest sigmoid(-2.5).
inline SplatScene bright_over_dim_scene(std::uint64_t seed) {
  SplatScene s = make_splat_scene(60, seed, 64, 48, 0.08, 0.2);
  for (int k = 0; k < 60; ++k) s.params[11 * k + 10] = k < 6 ? 3.0 : -2.5;
  return s;
}

// A scene like training sees: many small Gaussians (σ 2-11 pixels) over 16 x 16 tiles.
inline SplatScene large_scene() { return make_splat_scene(2000, 71, 256, 256, 0.01, 0.05); }

// Why `backend` cannot be tested in this process (this build lacks it, or no device is
// usable), or empty when it can. GPU tests skip, not fail, on such machines (STYLE
// "Differentiable code").
inline std::string why_backend_untestable(Backend backend) {
  if (backend != Backend::kCuda) return {};
  const CudaDeviceInfo& info = cuda_device_info();
  if (!info.compiled) return "this build has no CUDA back end (HISNEGS_HAVE_CUDA == 0): CUDA splatting not tested";
  if (!info.available) return "no usable CUDA device (" + info.reason + "): CUDA splatting not tested";
  return {};
}

// The scene's image (K.height x K.width) from `r`'s forward.
inline std::vector<float> render(SplatRenderer& r, const SplatScene& s, const SplatSettings& settings) {
  std::vector<float> img(static_cast<std::size_t>(s.K.width) * s.K.height);
  const std::vector<float> p = to_float(s.params);
  r.forward(p, s.K, s.view, settings, img);
  return img;
}

// max |a_i − b_i|; a NaN anywhere makes it NaN (so any bound `< tol` fails).
template <class A, class B>
double max_abs_diff(const std::vector<A>& a, const std::vector<B>& b) {
  double e = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    const double d = std::abs(double(a[i]) - double(b[i]));
    if (!(d <= e)) e = d;
  }
  return e;
}

// Pixels of `a` not within `tolerance` of `b` (|a − b| >= tolerance, or NaN).
template <class A, class B>
int count_far(const std::vector<A>& a, const std::vector<B>& b, double tolerance) {
  int far = 0;
  for (std::size_t i = 0; i < a.size(); ++i) far += std::abs(double(a[i]) - double(b[i])) < tolerance ? 0 : 1;
  return far;
}

// `n` weights uniform in [-1, 1] (a random dL/dimage), fixed by `seed`.
inline std::vector<double> random_weights(std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<double> w(n);
  for (double& x : w) x = u(rng);
  return w;
}

// Largest |g| per parameter kind (11): gradients of different kinds differ by orders
// of magnitude, so each is compared relative to the largest of its own kind.
inline std::vector<double> largest_per_kind(const std::vector<double>& g) {
  std::vector<double> largest(gmf::kGaussianParamCount, 0.0);
  for (std::size_t i = 0; i < g.size(); ++i) {
    largest[i % gmf::kGaussianParamCount] = std::max(largest[i % gmf::kGaussianParamCount], std::abs(g[i]));
  }
  return largest;
}

}  // namespace hisnegs::splat::testing
