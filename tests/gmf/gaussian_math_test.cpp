// gmf/gaussian_math: value against the mixture reference (Σ = R diag(s²) Rᵀ) and
// every analytic derivative against central finite differences in double, on
// random, nearly isotropic, very thin and far-away Gaussians.
#include "gmf/gaussian_math.hpp"

#include <gtest/gtest.h>

#include <array>
#include <random>

#include "gmf/gaussian_mixture.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::gmf {
namespace {

using Params = std::array<double, kGaussianParamCount>;

double value_at(const Params& p, const double x[3]) {
  GaussianFrame<double> f;
  prepare_gaussian(&p[kMeanX], &p[kLogScale0], &p[kRotW], p[kLogit], f);
  return evaluate_gaussian<double>(f, x, nullptr);
}

// Largest |analytic - central difference| relative to max(|analytic|, |fd|, floor),
// floor = 1e-7 × the largest derivative: a derivative that is ~0 (e.g. the rotation
// of a nearly isotropic Gaussian) is then judged absolutely against the gradient's
// scale, not relative to finite-difference noise.
double worst_relative_error(const Params& p, const double x[3]) {
  GaussianFrame<double> f;
  prepare_gaussian(&p[kMeanX], &p[kLogScale0], &p[kRotW], p[kLogit], f);
  double grad[kGaussianParamCount];
  evaluate_gaussian(f, x, grad);
  double largest = 0;
  for (int k = 0; k < kGaussianParamCount; ++k) largest = std::max(largest, std::abs(grad[k]));
  double worst = 0;
  // Initial Ridders steps on the scale each parameter acts on: a tenth of the
  // smallest standard deviation for means; for the quaternion a hundredth of
  // s_min / s_max (a rotation moves a long thin Gaussian by s_max δθ against a
  // width s_min); 0.01 for log-scales and the logit.
  const double s_min = std::exp(std::min({p[kLogScale0], p[kLogScale1], p[kLogScale2]}));
  const double s_max = std::exp(std::max({p[kLogScale0], p[kLogScale1], p[kLogScale2]}));
  for (int k = 0; k < kGaussianParamCount; ++k) {
    const double h0 = k <= kMeanZ ? 0.1 * s_min : (k >= kRotW && k <= kRotZ ? 0.01 * s_min / s_max : 0.01);
    const double fd = testing::ridders_derivative(
        [&](double v) {
          Params q = p;
          q[k] = v;
          return value_at(q, x);
        },
        p[k], h0);
    const double scale = std::max({std::abs(grad[k]), std::abs(fd), 1e-7 * largest});
    worst = std::max(worst, std::abs(grad[k] - fd) / scale);
  }
  return worst;
}

Params random_params(std::mt19937_64& rng, double log_scale_lo, double log_scale_hi) {
  std::uniform_real_distribution<double> u(-1, 1), ls(log_scale_lo, log_scale_hi), q(-1, 1);
  Params p{};
  for (int i = 0; i < 3; ++i) p[kMeanX + i] = 0.5 * u(rng);
  for (int i = 0; i < 3; ++i) p[kLogScale0 + i] = ls(rng);
  for (int i = 0; i < 4; ++i) p[kRotW + i] = q(rng);
  p[kRotW] += 1.5;  // keep |q| away from 0
  p[kLogit] = 2 * u(rng);
  return p;
}

TEST(GaussianMath, ValueMatchesTheCovarianceForm) {
  std::mt19937_64 rng(1);
  for (int t = 0; t < 50; ++t) {
    const Params p = random_params(rng, -3, -1);
    GaussianMixture m;
    GaussianParams g;
    for (int i = 0; i < 3; ++i) g.mean[i] = static_cast<float>(p[kMeanX + i]);
    for (int i = 0; i < 3; ++i) g.log_scale[i] = static_cast<float>(p[kLogScale0 + i]);
    for (int i = 0; i < 4; ++i) g.rotation[i] = static_cast<float>(p[kRotW + i]);
    g.intensity_logit = static_cast<float>(p[kLogit]);
    m.push_back(g);
    // Evaluate both from the float-rounded parameters.
    Params pf{};
    for (int i = 0; i < 3; ++i) pf[kMeanX + i] = g.mean[i];
    for (int i = 0; i < 3; ++i) pf[kLogScale0 + i] = g.log_scale[i];
    for (int i = 0; i < 4; ++i) pf[kRotW + i] = g.rotation[i];
    pf[kLogit] = g.intensity_logit;
    const double x[3] = {pf[kMeanX] + 0.05, pf[kMeanY] - 0.02, pf[kMeanZ] + 0.03};
    EXPECT_NEAR(value_at(pf, x), evaluate_mixture(m, Eigen::Vector3d(x[0], x[1], x[2])), 1e-12);
  }
}

TEST(GaussianMath, GradientMatchesCentralDifferences) {
  std::mt19937_64 rng(2);
  std::normal_distribution<double> n(0, 1);
  struct Case {
    const char* name;
    double ls_lo, ls_hi, offset_sigmas;
  };
  // typical, nearly isotropic, very thin (aspect 1:100), and far out (m ~ 12).
  for (const Case c : {Case{"typical", -3.5, -1.5, 1.0}, Case{"isotropic", -2.0, -1.999, 1.0},
                       Case{"thin", -5.0, -0.4, 1.0}, Case{"far", -3.0, -2.0, 2.0}}) {
    double worst = 0;
    for (int t = 0; t < 200; ++t) {
      const Params p = random_params(rng, c.ls_lo, c.ls_hi);
      GaussianFrame<double> f;
      prepare_gaussian(&p[kMeanX], &p[kLogScale0], &p[kRotW], p[kLogit], f);
      // A point at about `offset_sigmas` standard deviations along random local axes.
      double local[3], x[3];
      for (int i = 0; i < 3; ++i) local[i] = c.offset_sigmas * n(rng) / f.inv_scale[i];
      for (int r = 0; r < 3; ++r) {
        x[r] = f.mean[r] + f.R[3 * r] * local[0] + f.R[3 * r + 1] * local[1] + f.R[3 * r + 2] * local[2];
      }
      worst = std::max(worst, worst_relative_error(p, x));
    }
    // Ridders' extrapolated differences are accurate to ~1e-10 relative here.
    EXPECT_LT(worst, 1e-6) << c.name;
  }
}

TEST(GaussianMath, SupportBoxHoldsTheCutoffEllipsoid) {
  std::mt19937_64 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int t = 0; t < 100; ++t) {
    const Params p = random_params(rng, -3, -1);
    GaussianFrame<double> f;
    prepare_gaussian(&p[kMeanX], &p[kLogScale0], &p[kRotW], p[kLogit], f);
    double half[3];
    support_half_extents(f, 16.0, half);
    // Points on the m = 16 ellipsoid lie inside the box, and the box is tight along each axis.
    for (int s = 0; s < 50; ++s) {
      double dir[3] = {u(rng), u(rng), u(rng)};
      double z[3], x[3];
      const double len = std::sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
      for (int i = 0; i < 3; ++i) z[i] = 4.0 * dir[i] / len / f.inv_scale[i];
      for (int r = 0; r < 3; ++r) x[r] = f.R[3 * r] * z[0] + f.R[3 * r + 1] * z[1] + f.R[3 * r + 2] * z[2];
      for (int r = 0; r < 3; ++r) ASSERT_LE(std::abs(x[r]), half[r] * (1 + 1e-12));
      double zz[3];
      const double xm[3] = {x[0] + f.mean[0], x[1] + f.mean[1], x[2] + f.mean[2]};
      EXPECT_NEAR(mahalanobis(f, xm, zz), 16.0, 1e-9);
    }
  }
}

}  // namespace
}  // namespace hisnegs::gmf
