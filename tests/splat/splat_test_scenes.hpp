// Small random splatting scenes shared by the splat renderer tests: a few
// anisotropic, rotated Gaussians near the origin seen by an orbit camera.
#pragma once

#include <cmath>
#include <random>
#include <vector>

#include "splat/camera.hpp"
#include "splat/splat_renderer.hpp"

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
  return s.mode == MipMode::kHard ? g_b : std::max(g_b, 1.0 / (s.beta * std::exp(1.0)));
}

inline std::vector<float> to_float(const std::vector<double>& v) { return {v.begin(), v.end()}; }

}  // namespace hisnegs::splat::testing
