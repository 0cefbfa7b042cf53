// SPDX-License-Identifier: Apache-2.0
// The GMF residual block against Ceres' own numeric differentiation (Ridders'
// extrapolation, DynamicNumericDiffCostFunction) in double, and the Mahalanobis
// cutoff. The brick index and samples it is built from: brick_index_test.cpp,
// samples_test.cpp.
#include <ceres/dynamic_autodiff_cost_function.h>
#include <ceres/dynamic_numeric_diff_cost_function.h>
#include <gtest/gtest.h>

#include <random>

#include "gmf/detail/brick_cost.hpp"
#include "gmf/gaussian_math.hpp"
#include "gmf/samples.hpp"

namespace hisnegs::gmf {
namespace {

// A SampleSet with one brick of `n` random points in a box around `centre`.
SampleSet one_brick(std::mt19937_64& rng, const double centre[3], double half, int n) {
  std::uniform_real_distribution<double> u(-1, 1), v(0, 1);
  SampleSet s;
  s.brick_begin = {0};
  s.brick_origin = {{0, 0, 0}};
  for (int i = 0; i < n; ++i) {
    s.x.push_back(centre[0] + half * u(rng));
    s.y.push_back(centre[1] + half * u(rng));
    s.z.push_back(centre[2] + half * u(rng));
    s.value.push_back(v(rng));
    s.weight.push_back(i % 3 == 0 ? 2.5 : 1.0);
  }
  s.brick_begin.push_back(static_cast<std::uint32_t>(n));
  return s;
}

struct Mixture {
  std::vector<std::array<double, 11>> params;  // GaussianParam order
};

Mixture random_mixture(std::mt19937_64& rng, int k, double ls_lo, double ls_hi, double spread) {
  std::uniform_real_distribution<double> u(-1, 1), ls(ls_lo, ls_hi);
  Mixture m;
  for (int i = 0; i < k; ++i) {
    std::array<double, 11> p{};
    for (int a = 0; a < 3; ++a) p[kMeanX + a] = spread * u(rng);
    for (int a = 0; a < 3; ++a) p[kLogScale0 + a] = ls(rng);
    for (int a = 0; a < 4; ++a) p[kRotW + a] = u(rng);
    p[kRotW] += 1.5;
    p[kLogit] = u(rng);
    m.params.push_back(p);
  }
  return m;
}

// Parameter block pointers in BrickCost order.
std::vector<double*> blocks_of(Mixture& m) {
  std::vector<double*> b;
  for (auto& p : m.params) {
    b.push_back(&p[kMeanX]);
    b.push_back(&p[kLogScale0]);
    b.push_back(&p[kRotW]);
    b.push_back(&p[kLogit]);
  }
  return b;
}

// Residual-only functor around a BrickCost, for Ceres' numeric differentiation.
struct ResidualsOnly {
  const detail::BrickCost* cost;
  bool operator()(double const* const* p, double* r) const { return cost->Evaluate(p, r, nullptr); }
};

// Worst entry |analytic − numeric| / max(|analytic|, |numeric|, 1e-7 · max|J|).
double worst_jacobian_error(const SampleSet& s, Mixture& m, double cutoff) {
  std::vector<std::uint32_t> ids(m.params.size());
  for (std::size_t i = 0; i < ids.size(); ++i) ids[i] = static_cast<std::uint32_t>(i);
  const detail::BrickCost cost(s, 0, ids, cutoff);
  ceres::NumericDiffOptions nd;
  nd.ridders_relative_initial_step_size = 1e-3;
  ceres::DynamicNumericDiffCostFunction<ResidualsOnly, ceres::RIDDERS> numeric(new ResidualsOnly{&cost},
                                                                               ceres::TAKE_OWNERSHIP, nd);
  for (int size : cost.parameter_block_sizes()) numeric.AddParameterBlock(size);
  numeric.SetNumResiduals(cost.num_residuals());
  const std::vector<double*> blocks = blocks_of(m);
  const int nr = cost.num_residuals();
  std::vector<std::vector<double>> Ja(blocks.size()), Jn(blocks.size());
  std::vector<double*> pa, pn;
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    Ja[b].resize(static_cast<std::size_t>(nr) * cost.parameter_block_sizes()[b]);
    Jn[b].resize(Ja[b].size());
    pa.push_back(Ja[b].data());
    pn.push_back(Jn[b].data());
  }
  std::vector<double> ra(nr), rn(nr);
  EXPECT_TRUE(cost.Evaluate(blocks.data(), ra.data(), pa.data()));
  EXPECT_TRUE(numeric.Evaluate(blocks.data(), rn.data(), pn.data()));
  for (int i = 0; i < nr; ++i) EXPECT_EQ(ra[i], rn[i]);
  double largest = 0;
  for (const auto& J : Ja)
    for (double v : J) largest = std::max(largest, std::abs(v));
  double worst = 0;
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    for (std::size_t i = 0; i < Ja[b].size(); ++i) {
      const double scale = std::max({std::abs(Ja[b][i]), std::abs(Jn[b][i]), 1e-7 * largest});
      worst = std::max(worst, std::abs(Ja[b][i] - Jn[b][i]) / scale);
    }
  }
  return worst;
}

TEST(BrickCost, JacobianMatchesCeresRiddersDifferentiation) {
  std::mt19937_64 rng(4);
  struct Case {
    const char* name;
    double ls_lo, ls_hi, spread;
  };
  // typical; nearly isotropic; very thin (1:100); far away (means spread over ±0.25
  // around a brick of half-width 0.05: many samples sit at m ~ 10); and a brick
  // at the edge of the world box.
  for (const Case c : {Case{"typical", -3.2, -2.2, 0.05}, Case{"isotropic", -2.5, -2.499, 0.05},
                       Case{"thin", -5.0, -1.5, 0.05}, Case{"far", -2.8, -2.3, 0.25}}) {
    for (int t = 0; t < 5; ++t) {
      const double centre[3] = {0.0, 0.0, 0.0};
      const SampleSet s = one_brick(rng, centre, 0.05, 40);
      Mixture m = random_mixture(rng, 4, c.ls_lo, c.ls_hi, c.spread);
      // No cutoff here: f is smooth, so its derivative is exact everywhere.
      EXPECT_LT(worst_jacobian_error(s, m, 1e300), 1e-6) << c.name << " trial " << t;
    }
  }
  // Edge brick: samples on the box face x = 1, Gaussians straddling it.
  const double edge[3] = {1.0, -0.5, 0.3};
  const SampleSet s = one_brick(rng, edge, 0.04, 40);
  Mixture m = random_mixture(rng, 3, -3.0, -2.2, 0.04);
  for (auto& p : m.params) {
    for (int a = 0; a < 3; ++a) p[kMeanX + a] += edge[a];
  }
  EXPECT_LT(worst_jacobian_error(s, m, 1e300), 1e-6) << "edge";
}

// Automatic differentiation (Jets) is exact up to rounding, so the analytic
// Jacobian must agree with it to ~1e-12 relative to the Jacobian's scale.
TEST(BrickCost, JacobianMatchesCeresAutomaticDifferentiation) {
  std::mt19937_64 rng(8);
  const double centre[3] = {0.1, -0.2, 0.05};
  const SampleSet s = one_brick(rng, centre, 0.05, 30);
  Mixture m = random_mixture(rng, 5, -4.5, -1.5, 0.08);
  for (auto& p : m.params) {
    for (int a = 0; a < 3; ++a) p[kMeanX + a] += centre[a];
  }
  std::vector<std::uint32_t> ids(m.params.size());
  for (std::size_t i = 0; i < ids.size(); ++i) ids[i] = static_cast<std::uint32_t>(i);
  const detail::BrickCost cost(s, 0, ids, 16.0);
  ceres::DynamicAutoDiffCostFunction<detail::BrickResiduals, 4> autodiff(
      new detail::BrickResiduals{&s, 0, 30, m.params.size(), 16.0});
  for (int size : cost.parameter_block_sizes()) autodiff.AddParameterBlock(size);
  autodiff.SetNumResiduals(cost.num_residuals());
  const std::vector<double*> blocks = blocks_of(m);
  std::vector<std::vector<double>> Ja, Jd;
  std::vector<double*> pa, pd;
  for (int size : cost.parameter_block_sizes()) {
    Ja.emplace_back(30 * size);
    Jd.emplace_back(30 * size);
    pa.push_back(Ja.back().data());
    pd.push_back(Jd.back().data());
  }
  std::vector<double> ra(30), rd(30);
  ASSERT_TRUE(cost.Evaluate(blocks.data(), ra.data(), pa.data()));
  ASSERT_TRUE(autodiff.Evaluate(blocks.data(), rd.data(), pd.data()));
  double largest = 0;
  for (const auto& J : Ja)
    for (double v : J) largest = std::max(largest, std::abs(v));
  for (std::size_t b = 0; b < Ja.size(); ++b)
    for (std::size_t i = 0; i < Ja[b].size(); ++i) ASSERT_NEAR(Ja[b][i], Jd[b][i], 1e-12 * largest) << b << " " << i;
  for (int i = 0; i < 30; ++i) EXPECT_NEAR(ra[i], rd[i], 1e-15);
}

TEST(BrickCost, CutoffDropsGaussiansBeyondDelta) {
  // One Gaussian at the origin, samples at m = 9 and m = 25 along its first axis.
  SampleSet s;
  s.brick_begin = {0, 2};
  s.brick_origin = {{0, 0, 0}};
  const double sigma = 0.1;
  s.x = {3 * sigma, 5 * sigma};
  s.y = {0, 0};
  s.z = {0, 0};
  s.value = {0, 0};
  s.weight = {1, 1};
  Mixture m;
  m.params.push_back({0, 0, 0, std::log(sigma), std::log(sigma), std::log(sigma), 1, 0, 0, 0, 0.0});
  const std::vector<std::uint32_t> ids{0};
  const detail::BrickCost cost(s, 0, ids, 16.0);
  const std::vector<double*> blocks = blocks_of(m);
  double r[2];
  ASSERT_TRUE(cost.Evaluate(blocks.data(), r, nullptr));
  EXPECT_NEAR(r[0], 0.5 * std::exp(-4.5), 1e-15);  // a = sigmoid(0) = 0.5, m = 9 <= 16
  EXPECT_EQ(r[1], 0.0);                            // m = 25 > 16: outside the support
}

}  // namespace
}  // namespace hisnegs::gmf
