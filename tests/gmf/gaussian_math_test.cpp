// SPDX-License-Identifier: Apache-2.0
// gmf/gaussian_math: value against the mixture reference (Σ = R diag(s²) Rᵀ) and
// every analytic derivative against central finite differences in double, on
// random, nearly isotropic, very thin and far-away Gaussians; and each forward
// op's VJP against Ridders differences of <upstream gradient, op(input)>.
#include "gmf/core/gaussian_math.hpp"

#include <gtest/gtest.h>

#include <array>
#include <random>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"
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

// ----- each VJP against its forward op -----
//
// For an op y = F(x) and a random upstream gradient u = dL/dy, L(x) = <u, F(x)>;
// the VJP's dL/dx must equal the Ridders derivative of L along each input.

// Worst |analytic − Ridders| / max(|analytic|, |fd|, 1e-8 · max_i |analytic_i|)
// over the inputs: a derivative that is ~0 is judged against the gradient's scale.
// `h0[i]` is the initial Ridders step of input i.
template <class Loss>
double worst_vjp_error(const std::vector<double>& x, const std::vector<double>& analytic, const std::vector<double>& h0,
                       Loss&& loss) {
  double largest = 0;
  for (double g : analytic) largest = std::max(largest, std::abs(g));
  double worst = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    const double fd = testing::ridders_derivative(
        [&](double v) {
          std::vector<double> y = x;
          y[i] = v;
          return loss(y);
        },
        x[i], h0[i]);
    const double scale = std::max({std::abs(analytic[i]), std::abs(fd), 1e-8 * largest});
    worst = std::max(worst, std::abs(analytic[i] - fd) / scale);
  }
  return worst;
}

std::vector<double> normals(std::mt19937_64& rng, int n, double sd = 1.0) {
  std::normal_distribution<double> d(0, sd);
  std::vector<double> v(n);
  for (double& x : v) x = d(rng);
  return v;
}

double dot(const std::vector<double>& a, const double* b) {
  double s = 0;
  for (std::size_t i = 0; i < a.size(); ++i) s += a[i] * b[i];
  return s;
}

// Ridders differences here are accurate to ~1e-10 relative; 1e-7 leaves room
// for cancellation in the sums of products without hiding a wrong term (a wrong
// term gives errors of order 1).
constexpr double kVjpTolerance = 1e-7;

TEST(GaussianMath, SigmoidVjpMatchesCentralDifferences) {
  std::mt19937_64 rng(201);
  std::uniform_real_distribution<double> logit(-8, 8);
  double worst = 0;
  for (int t = 0; t < 100; ++t) {
    const std::vector<double> x = {logit(rng)};
    const double u = normals(rng, 1)[0];
    const double a = sigmoid(x[0]);
    const std::vector<double> analytic = {sigmoid_vjp(a, u)};
    worst = std::max(
        worst, worst_vjp_error(x, analytic, {0.1}, [&](const std::vector<double>& y) { return u * sigmoid(y[0]); }));
  }
  EXPECT_LT(worst, kVjpTolerance);
}

// Raw quaternions of norm ~0.3 to ~3: the VJP projects out the radial part and
// divides by |q|.
TEST(GaussianMath, QuatNormalizeVjpMatchesCentralDifferences) {
  std::mt19937_64 rng(203);
  std::uniform_real_distribution<double> norm(0.3, 3.0);
  double worst = 0;
  for (int t = 0; t < 100; ++t) {
    std::vector<double> q = normals(rng, 4);
    const double scale = norm(rng) / std::sqrt(dot(q, q.data()));
    for (double& c : q) c *= scale;
    const std::vector<double> u = normals(rng, 4);
    double q_hat[4], dq[4];
    const double inv_norm = quat_normalize(q.data(), q_hat);
    quat_normalize_vjp(q_hat, inv_norm, u.data(), dq);
    const double h = 0.01 / inv_norm;
    worst = std::max(worst, worst_vjp_error(q, {dq, dq + 4}, {h, h, h, h}, [&](const std::vector<double>& y) {
                       double y_hat[4];
                       (void)quat_normalize(y.data(), y_hat);
                       return dot(u, y_hat);
                     }));
  }
  EXPECT_LT(worst, kVjpTolerance);
}

// The polynomial R(q) for q taken as given (not unit): every one of its terms.
TEST(GaussianMath, QuatToRotmatVjpMatchesCentralDifferences) {
  std::mt19937_64 rng(205);
  double worst = 0;
  for (int t = 0; t < 100; ++t) {
    const std::vector<double> q = normals(rng, 4);
    const std::vector<double> u = normals(rng, 9);
    double dq[4];
    quat_to_rotmat_vjp(q.data(), u.data(), dq);
    worst = std::max(worst, worst_vjp_error(q, {dq, dq + 4}, {0.1, 0.1, 0.1, 0.1}, [&](const std::vector<double>& y) {
                       double R[9];
                       quat_to_rotmat(y.data(), R);
                       return dot(u, R);
                     }));
  }
  EXPECT_LT(worst, kVjpTolerance);
}

// Inputs: the 9 entries of R (any matrix: the op does not need a rotation) and
// the 3 scales s. covariance_from_axes_vjp ASSUMES A SYMMETRIC dL/dΣ: it forms
// dL/dM = 2 (dL/dΣ) M, which is (G + Gᵀ) M only for G = Gᵀ. Σ is symmetric, so
// an upstream gradient G can always be replaced by (G + Gᵀ) / 2 first.
struct CovarianceCase {
  std::vector<double> x;  // R (9, row-major), then s (3)
  std::vector<double> G;  // dL/dΣ (9, row-major)
};

CovarianceCase covariance_case(std::mt19937_64& rng, bool symmetric) {
  std::uniform_real_distribution<double> s(0.05, 2.0);
  CovarianceCase c{normals(rng, 9), normals(rng, 9)};
  for (int i = 0; i < 3; ++i) c.x.push_back(s(rng));
  if (symmetric) {
    for (int r = 0; r < 3; ++r)
      for (int col = 0; col < r; ++col) c.G[3 * col + r] = c.G[3 * r + col];
  }
  return c;
}

double covariance_error(const CovarianceCase& c, const std::vector<double>& upstream) {
  double dR[9], ds[3];
  covariance_from_axes_vjp(c.x.data(), c.x.data() + 9, upstream.data(), dR, ds);
  std::vector<double> analytic(dR, dR + 9);
  analytic.insert(analytic.end(), ds, ds + 3);
  return worst_vjp_error(c.x, analytic, std::vector<double>(12, 0.05), [&](const std::vector<double>& y) {
    double cov[9];
    covariance_from_axes(y.data(), y.data() + 9, cov);
    return dot(c.G, cov);  // L = <G, Σ>, G as given
  });
}

TEST(GaussianMath, CovarianceFromAxesVjpMatchesCentralDifferencesForSymmetricUpstream) {
  std::mt19937_64 rng(207);
  double worst = 0;
  for (int t = 0; t < 100; ++t) {
    const CovarianceCase c = covariance_case(rng, true);
    worst = std::max(worst, covariance_error(c, c.G));
  }
  EXPECT_LT(worst, kVjpTolerance);
}

// A non-symmetric G: the VJP of its symmetric part is right, the VJP of G itself
// is not (the documented precondition matters).
TEST(GaussianMath, CovarianceFromAxesVjpNeedsTheSymmetricPartOfTheUpstream) {
  std::mt19937_64 rng(209);
  double worst_sym = 0, best_raw = 1e300;
  for (int t = 0; t < 50; ++t) {
    const CovarianceCase c = covariance_case(rng, false);
    std::vector<double> sym(9);
    for (int r = 0; r < 3; ++r)
      for (int col = 0; col < 3; ++col) sym[3 * r + col] = 0.5 * (c.G[3 * r + col] + c.G[3 * col + r]);
    worst_sym = std::max(worst_sym, covariance_error(c, sym));
    best_raw = std::min(best_raw, covariance_error(c, c.G));
  }
  EXPECT_LT(worst_sym, kVjpTolerance);
  EXPECT_GT(best_raw, 1e-3);
}

// Inputs: μ (3), the 9 entries of R taken as free (as mahalanobis_vjp's dL/dR
// is), log s (3); x fixed at a few standard deviations from μ.
TEST(GaussianMath, MahalanobisVjpMatchesCentralDifferences) {
  std::mt19937_64 rng(211);
  std::uniform_real_distribution<double> ls(-3, -0.5);
  double worst = 0;
  for (int t = 0; t < 100; ++t) {
    std::vector<double> x = normals(rng, 3, 0.3);  // mean
    const std::vector<double> q = normals(rng, 4);
    double q_hat[4], R[9];
    (void)quat_normalize(q.data(), q_hat);
    quat_to_rotmat(q_hat, R);
    const std::vector<double> noise = normals(rng, 9, 0.1);  // R need not be a rotation here
    for (int i = 0; i < 9; ++i) x.push_back(R[i] + noise[i]);
    for (int i = 0; i < 3; ++i) x.push_back(ls(rng));
    const std::vector<double> off = normals(rng, 3, 1.5);
    const double p[3] = {x[0] + off[0] * std::exp(x[12]), x[1] + off[1] * std::exp(x[13]),
                         x[2] + off[2] * std::exp(x[14])};
    const double u = normals(rng, 1)[0];
    auto frame = [](const std::vector<double>& y) {
      GaussianFrame<double> f{};
      for (int i = 0; i < 3; ++i) {
        f.mean[i] = y[i];
        f.scale[i] = std::exp(y[12 + i]);
        f.inv_scale[i] = std::exp(-y[12 + i]);
      }
      for (int i = 0; i < 9; ++i) f.R[i] = y[3 + i];
      return f;
    };
    const GaussianFrame<double> f = frame(x);
    double z[3], dmean[3], dR[9], dls[3];
    (void)mahalanobis(f, p, z);
    mahalanobis_vjp(f, p, z, u, dmean, dR, dls);
    std::vector<double> analytic(dmean, dmean + 3);
    analytic.insert(analytic.end(), dR, dR + 9);
    analytic.insert(analytic.end(), dls, dls + 3);
    std::vector<double> h0(15, 0.01);
    for (int i = 0; i < 3; ++i) h0[i] = 0.1 * std::exp(std::min({x[12], x[13], x[14]}));
    worst = std::max(worst, worst_vjp_error(x, analytic, h0, [&](const std::vector<double>& y) {
                       double zz[3];
                       return u * mahalanobis(frame(y), p, zz);
                     }));
  }
  EXPECT_LT(worst, kVjpTolerance);
}

// dL/dq of a raw quaternion through R(q / |q|): quat_to_rotmat_vjp chained with
// quat_normalize_vjp.
TEST(GaussianMath, RotationVjpMatchesCentralDifferences) {
  std::mt19937_64 rng(213);
  std::uniform_real_distribution<double> norm(0.3, 3.0);
  double worst = 0;
  for (int t = 0; t < 100; ++t) {
    std::vector<double> q = normals(rng, 4);
    const double scale = norm(rng) / std::sqrt(dot(q, q.data()));
    for (double& c : q) c *= scale;
    const std::vector<double> u = normals(rng, 9);
    const double mean[3] = {0.1, -0.2, 0.3}, log_scale[3] = {-1, -2, -1.5};
    GaussianFrame<double> f;
    prepare_gaussian(mean, log_scale, q.data(), 0.3, f);
    double dq[4];
    rotation_vjp(f, u.data(), dq);
    const double h = 0.01 / f.inv_q_norm;
    worst = std::max(worst, worst_vjp_error(q, {dq, dq + 4}, {h, h, h, h}, [&](const std::vector<double>& y) {
                       double y_hat[4], R[9];
                       (void)quat_normalize(y.data(), y_hat);
                       quat_to_rotmat(y_hat, R);
                       return dot(u, R);
                     }));
  }
  EXPECT_LT(worst, kVjpTolerance);
}

}  // namespace
}  // namespace hisnegs::gmf
