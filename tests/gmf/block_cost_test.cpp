// SPDX-License-Identifier: Apache-2.0
// The GMF residual block against Ceres' own numeric differentiation (Ridders'
// extrapolation, DynamicNumericDiffCostFunction) in double, and the Mahalanobis
// cutoff. The block index and samples it is built from: block_index_test.cpp,
// samples_test.cpp.
#include <ceres/dynamic_autodiff_cost_function.h>
#include <ceres/dynamic_numeric_diff_cost_function.h>
#include <gtest/gtest.h>

#include <random>
#include <span>
#include <string>

#include "gmf/detail/block_cost.hpp"
#include "gmf/core/gaussian_math.hpp"
#include "gmf/samples.hpp"

namespace hisnegs::gmf {
namespace {

// A SampleSet with one block of `n` random points in a box around `centre`.
SampleSet one_block(std::mt19937_64& rng, const double centre[3], double half, int n) {
  std::uniform_real_distribution<double> u(-1, 1), v(0, 1);
  SampleSet s;
  s.block_begin = {0};
  s.block_origin = {{0, 0, 0}};
  for (int i = 0; i < n; ++i) {
    s.x.push_back(centre[0] + half * u(rng));
    s.y.push_back(centre[1] + half * u(rng));
    s.z.push_back(centre[2] + half * u(rng));
    s.value.push_back(v(rng));
    s.weight.push_back(i % 3 == 0 ? 2.5 : 1.0);
  }
  s.block_begin.push_back(static_cast<std::uint32_t>(n));
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

// Parameter block pointers in BlockCost order.
std::vector<double*> blocks_of(Mixture& m) {
  std::vector<double*> b;
  for (auto& p : m.params) b.push_back(p.data());
  return b;
}

// Fixed terms at each sample, as the brick solver forms them: the sum and the
// online softmax of the terms of `k` random Gaussians that are not free.
std::vector<PointTerms<double>> random_fixed_terms(std::mt19937_64& rng, int samples, double beta) {
  std::uniform_real_distribution<double> v(0, 0.8);
  std::vector<PointTerms<double>> out;
  for (int j = 0; j < samples; ++j) {
    PointTerms<double> t = no_terms<double>();
    for (int i = 0; i < j % 4; ++i) {  // 0 to 3 fixed terms: also samples with none
      const double g = v(rng);
      t.sum += g;
      softmax_add(t.soft, g, beta);
      t.max = std::max(t.max, g);
    }
    out.push_back(t);
  }
  return out;
}

// Residual-only functor around a BlockCost, for Ceres' numeric differentiation.
struct ResidualsOnly {
  const detail::BlockCost* cost;
  bool operator()(double const* const* p, double* r) const { return cost->Evaluate(p, r, nullptr); }
};

// Worst entry |analytic − numeric| / max(|analytic|, |numeric|, 1e-7 · max|J|).
// `model` is the aggregation (sum or softmax at β); `fixed`, when not empty, the
// terms of Gaussians held fixed at each sample.
double worst_jacobian_error(const SampleSet& s, Mixture& m, const MixtureModel& model,
                            std::span<const PointTerms<double>> fixed = {}) {
  const detail::BlockCost cost(s, 0, m.params.size(), model, fixed);
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

TEST(BlockCost, JacobianMatchesCeresRiddersDifferentiation) {
  std::mt19937_64 rng(4);
  struct Case {
    const char* name;
    double ls_lo, ls_hi, spread;
  };
  // typical; nearly isotropic; very thin (1:100); far away (means spread over ±0.25
  // around a block of half-width 0.05: many samples sit at m ~ 10); and a block
  // at the edge of the world box.
  for (const Case c : {Case{"typical", -3.2, -2.2, 0.05}, Case{"isotropic", -2.5, -2.499, 0.05},
                       Case{"thin", -5.0, -1.5, 0.05}, Case{"far", -2.8, -2.3, 0.25}}) {
    for (int t = 0; t < 5; ++t) {
      const double centre[3] = {0.0, 0.0, 0.0};
      const SampleSet s = one_block(rng, centre, 0.05, 40);
      Mixture m = random_mixture(rng, 4, c.ls_lo, c.ls_hi, c.spread);
      // No cutoff here: f is smooth, so its derivative is exact everywhere.
      EXPECT_LT(worst_jacobian_error(s, m, MixtureModel{.cutoff = 1e300}), 1e-6) << c.name << " trial " << t;
    }
  }
  // Edge block: samples on the box face x = 1, Gaussians straddling it.
  const double edge[3] = {1.0, -0.5, 0.3};
  const SampleSet s = one_block(rng, edge, 0.04, 40);
  Mixture m = random_mixture(rng, 3, -3.0, -2.2, 0.04);
  for (auto& p : m.params) {
    for (int a = 0; a < 3; ++a) p[kMeanX + a] += edge[a];
  }
  EXPECT_LT(worst_jacobian_error(s, m, MixtureModel{.cutoff = 1e300}), 1e-6) << "edge";
}

// The sum with fixed terms: they shift the residual, not its Jacobian.
TEST(BlockCost, SumJacobianWithFixedTermsMatchesRidders) {
  std::mt19937_64 rng(23);
  const double centre[3] = {0.0, 0.0, 0.0};
  const SampleSet s = one_block(rng, centre, 0.05, 40);
  Mixture m = random_mixture(rng, 4, -3.2, -2.2, 0.05);
  const std::vector<PointTerms<double>> fixed = random_fixed_terms(rng, 40, 1.0);
  EXPECT_LT(worst_jacobian_error(s, m, MixtureModel{.cutoff = 1e300}, fixed), 1e-6);
}

// Automatic differentiation (Jets) is exact up to rounding, so the analytic
// Jacobian must agree with it to ~1e-12 relative to the Jacobian's scale.
void expect_matches_autodiff(const SampleSet& s, Mixture& m, const MixtureModel& model,
                             std::span<const PointTerms<double>> fixed, const char* what) {
  const int n = static_cast<int>(s.x.size());
  const detail::BlockCost cost(s, 0, m.params.size(), model, fixed);
  ceres::DynamicAutoDiffCostFunction<detail::BlockResiduals, 4> autodiff(
      new detail::BlockResiduals{&s, 0, static_cast<std::uint32_t>(n), m.params.size(), model, fixed});
  for (int size : cost.parameter_block_sizes()) autodiff.AddParameterBlock(size);
  autodiff.SetNumResiduals(cost.num_residuals());
  const std::vector<double*> blocks = blocks_of(m);
  std::vector<std::vector<double>> Ja, Jd;
  std::vector<double*> pa, pd;
  for (int size : cost.parameter_block_sizes()) {
    Ja.emplace_back(n * size);
    Jd.emplace_back(n * size);
    pa.push_back(Ja.back().data());
    pd.push_back(Jd.back().data());
  }
  std::vector<double> ra(n), rd(n);
  ASSERT_TRUE(cost.Evaluate(blocks.data(), ra.data(), pa.data()));
  ASSERT_TRUE(autodiff.Evaluate(blocks.data(), rd.data(), pd.data()));
  double largest = 0;
  for (const auto& J : Ja)
    for (double v : J) largest = std::max(largest, std::abs(v));
  for (std::size_t b = 0; b < Ja.size(); ++b)
    for (std::size_t i = 0; i < Ja[b].size(); ++i)
      ASSERT_NEAR(Ja[b][i], Jd[b][i], 1e-12 * largest) << what << ": block " << b << " entry " << i;
  for (int i = 0; i < n; ++i) EXPECT_NEAR(ra[i], rd[i], 1e-15) << what;
}

TEST(BlockCost, JacobianMatchesCeresAutomaticDifferentiation) {
  std::mt19937_64 rng(8);
  const double centre[3] = {0.1, -0.2, 0.05};
  const SampleSet s = one_block(rng, centre, 0.05, 30);
  Mixture m = random_mixture(rng, 5, -4.5, -1.5, 0.08);
  for (auto& p : m.params) {
    for (int a = 0; a < 3; ++a) p[kMeanX + a] += centre[a];
  }
  expect_matches_autodiff(s, m, MixtureModel{}, {}, "sum");
  const std::vector<PointTerms<double>> fixed = random_fixed_terms(rng, 30, 32.0);
  expect_matches_autodiff(s, m, MixtureModel{.aggregation = Aggregation::kSoftmax, .beta = 32.0}, {}, "softmax");
  expect_matches_autodiff(s, m, MixtureModel{.aggregation = Aggregation::kSoftmax, .beta = 32.0}, fixed,
                          "softmax with fixed terms");
  // The max: automatic differentiation follows the branch the max takes, which is the
  // subgradient BlockCost gives (1 for the largest term, 0 for the others).
  expect_matches_autodiff(s, m, MixtureModel{.aggregation = Aggregation::kMax}, {}, "max");
  expect_matches_autodiff(s, m, MixtureModel{.aggregation = Aggregation::kMax}, fixed, "max with fixed terms");
}

// Worst |analytic − central difference| over the Jacobian, relative to its largest
// entry; the difference steps each parameter by h (absolute).
double worst_central_difference_error(const SampleSet& s, Mixture& m, const MixtureModel& model,
                                      std::span<const PointTerms<double>> fixed, double h) {
  const detail::BlockCost cost(s, 0, m.params.size(), model, fixed);
  const int nr = cost.num_residuals();
  std::vector<double*> blocks = blocks_of(m);
  std::vector<std::vector<double>> J(blocks.size(), std::vector<double>(static_cast<std::size_t>(nr) * 11));
  std::vector<double*> pj;
  for (auto& b : J) pj.push_back(b.data());
  std::vector<double> r(nr), up(nr), down(nr);
  EXPECT_TRUE(cost.Evaluate(blocks.data(), r.data(), pj.data()));
  double largest = 0, worst = 0;
  for (const auto& b : J)
    for (double v : b) largest = std::max(largest, std::abs(v));
  for (std::size_t b = 0; b < blocks.size(); ++b) {
    for (int c = 0; c < 11; ++c) {
      const double keep = blocks[b][c];
      blocks[b][c] = keep + h;
      cost.Evaluate(blocks.data(), up.data(), nullptr);
      blocks[b][c] = keep - h;
      cost.Evaluate(blocks.data(), down.data(), nullptr);
      blocks[b][c] = keep;
      for (int i = 0; i < nr; ++i) {
        const double numeric = (up[i] - down[i]) / (2 * h);
        worst = std::max(worst, std::abs(J[b][static_cast<std::size_t>(i) * 11 + c] - numeric) / largest);
      }
    }
  }
  return worst;
}

// The softmax residual f_β = Σ w_k g_k, w = softmax(β g): its analytic Jacobian
// (∂f/∂g_k = w_k (1 + β (g_k − f)) chained through ∂g/∂θ) for the typical, thin,
// far-away and overlapping-at-a-voxel cases, each without and with fixed terms, at
// a low and a high β of the continuation schedule: against Ceres' automatic
// differentiation (exact) and against central differences of fixed step. Ceres'
// Ridders is not used here: with its step relative to |θ|, it returned O(1)-wrong
// columns on the steep β = 64 softmax (and on thin Gaussians at β = 8), where both
// the Jets and a plain 1e-6 central difference agree with the analytic Jacobian.
TEST(BlockCost, SoftmaxJacobianMatchesAutomaticAndNumericDifferentiation) {
  std::mt19937_64 rng(17);
  struct Case {
    const char* name;
    double ls_lo, ls_hi, spread;
  };
  for (const double beta : {8.0, 64.0}) {
    for (const Case c : {Case{"typical", -3.2, -2.2, 0.05}, Case{"thin", -5.0, -1.5, 0.05},
                         Case{"far", -2.8, -2.3, 0.25}, Case{"overlapping", -2.6, -2.4, 0.002}}) {
      for (const bool with_fixed : {false, true}) {
        for (int t = 0; t < 3; ++t) {
          const double centre[3] = {0.0, 0.0, 0.0};
          const SampleSet s = one_block(rng, centre, 0.05, 40);
          Mixture m = random_mixture(rng, 4, c.ls_lo, c.ls_hi, c.spread);
          const std::vector<PointTerms<double>> fixed =
              with_fixed ? random_fixed_terms(rng, 40, beta) : std::vector<PointTerms<double>>{};
          const MixtureModel model{.aggregation = Aggregation::kSoftmax, .beta = beta, .cutoff = 1e300};
          const std::string what =
              std::string(c.name) + " beta " + std::to_string(beta) + (with_fixed ? " with fixed terms" : "");
          expect_matches_autodiff(s, m, model, fixed, what.c_str());
          EXPECT_LT(worst_central_difference_error(s, m, model, fixed, 1e-6), 1e-6) << what << " trial " << t;
        }
      }
    }
  }
}

TEST(BlockCost, CutoffDropsGaussiansBeyondDelta) {
  // One Gaussian at the origin, samples at m = 9 and m = 25 along its first axis.
  SampleSet s;
  s.block_begin = {0, 2};
  s.block_origin = {{0, 0, 0}};
  const double sigma = 0.1;
  s.x = {3 * sigma, 5 * sigma};
  s.y = {0, 0};
  s.z = {0, 0};
  s.value = {0, 0};
  s.weight = {1, 1};
  Mixture m;
  m.params.push_back({0, 0, 0, std::log(sigma), std::log(sigma), std::log(sigma), 1, 0, 0, 0, 0.0});
  const std::vector<std::uint32_t> ids{0};
  const detail::BlockCost cost(s, 0, ids.size(), MixtureModel{});
  const std::vector<double*> blocks = blocks_of(m);
  double r[2];
  ASSERT_TRUE(cost.Evaluate(blocks.data(), r, nullptr));
  EXPECT_NEAR(r[0], 0.5 * std::exp(-4.5), 1e-15);  // a = sigmoid(0) = 0.5, m = 9 <= 16
  EXPECT_EQ(r[1], 0.0);                            // m = 25 > 16: outside the support
}

}  // namespace
}  // namespace hisnegs::gmf
