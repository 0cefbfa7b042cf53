// SPDX-License-Identifier: Apache-2.0
// gmf/core/aggregation.hpp: the online softmax against its closed form, order and
// grouping independence, f_β → max as β grows (and how fast: the β the fit's
// continuation ends at), and ∂f_β/∂g_k against a central difference.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "gmf/core/aggregation.hpp"

namespace hisnegs::gmf {
namespace {

// Σ g e^{βg} / Σ e^{βg}, shifted by the largest βg (the closed form of Eq. 8).
double softmax_direct(const std::vector<double>& g, double beta) {
  const double top = beta * *std::max_element(g.begin(), g.end());
  double S = 0, W = 0;
  for (double v : g) {
    S += std::exp(beta * v - top);
    W += std::exp(beta * v - top) * v;
  }
  return W / S;
}

double softmax_online(const std::vector<double>& g, double beta) {
  SoftMaxState<double> st;
  softmax_init(st);
  for (double v : g) softmax_add(st, v, beta);
  return softmax_value(st);
}

std::vector<double> random_terms(std::mt19937_64& rng, int n) {
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<double> g(n);
  for (double& v : g) v = u(rng);
  return g;
}

TEST(Aggregation, OnlineSoftmaxEqualsItsClosedFormInAnyOrderAndGrouping) {
  std::mt19937_64 rng(3);
  for (const double beta : {0.5, 8.0, 64.0, 1e4}) {
    for (int t = 0; t < 20; ++t) {
      std::vector<double> g = random_terms(rng, 1 + t % 9);
      const double direct = softmax_direct(g, beta);
      EXPECT_NEAR(softmax_online(g, beta), direct, 1e-14) << beta;
      std::shuffle(g.begin(), g.end(), rng);
      EXPECT_NEAR(softmax_online(g, beta), direct, 1e-14) << beta;
      // Two groups merged equal one pass over all terms.
      SoftMaxState<double> a, b;
      softmax_init(a);
      softmax_init(b);
      for (std::size_t i = 0; i < g.size(); ++i) softmax_add(i % 2 ? a : b, g[i], beta);
      softmax_merge(a, b);
      EXPECT_NEAR(softmax_value(a), direct, 1e-14) << beta;
    }
  }
}

TEST(Aggregation, NoTermsGiveZeroAndMergingNothingChangesNothing) {
  SoftMaxState<double> empty, st;
  softmax_init(empty);
  softmax_init(st);
  EXPECT_EQ(softmax_value(empty), 0.0);
  softmax_add(st, 0.3, 10.0);
  softmax_merge(st, empty);
  EXPECT_EQ(softmax_value(st), 0.3);
  softmax_merge(empty, st);
  EXPECT_EQ(softmax_value(empty), 0.3);
}

// f_β lies between the mean and the max and tends to the max as β grows: for
// terms in [0, 1] the gap is at most (n − 1)/(e β) (each smaller term g_k adds at
// most (max − g_k) e^{−β (max − g_k)} ≤ 1/(e β) to it).
TEST(Aggregation, SoftmaxTendsToTheMaxAsBetaGrows) {
  std::mt19937_64 rng(5);
  for (int t = 0; t < 50; ++t) {
    const std::vector<double> g = random_terms(rng, 2 + t % 7);
    const double max = *std::max_element(g.begin(), g.end());
    double previous = -1;
    for (const double beta : {1.0, 4.0, 16.0, 64.0, 256.0, 4096.0}) {
      const double f = softmax_online(g, beta);
      EXPECT_LE(f, max + 1e-15);
      EXPECT_GE(f, previous - 1e-15) << "f_β grows with β";
      EXPECT_LE(max - f, static_cast<double>(g.size() - 1) / (std::exp(1.0) * beta) + 1e-15) << beta;
      previous = f;
    }
  }
}

TEST(Aggregation, DerivativeWithRespectToATermMatchesCentralDifferences) {
  std::mt19937_64 rng(9);
  for (const double beta : {1.0, 8.0, 64.0}) {
    for (int t = 0; t < 10; ++t) {
      std::vector<double> g = random_terms(rng, 2 + t % 5);
      SoftMaxState<double> st;
      softmax_init(st);
      for (double v : g) softmax_add(st, v, beta);
      const double f = softmax_value(st);
      for (std::size_t k = 0; k < g.size(); ++k) {
        const double analytic = softmax_dvalue_dterm(g[k], beta, st.m, st.S, f);
        const double h = 1e-6;
        std::vector<double> up = g, down = g;
        up[k] += h;
        down[k] -= h;
        const double numeric = (softmax_online(up, beta) - softmax_online(down, beta)) / (2 * h);
        EXPECT_NEAR(analytic, numeric, 1e-6 * std::max(1.0, std::abs(numeric))) << beta << " " << k;
      }
    }
  }
}

// The one policy of the fit and the splatting: the value of every aggregation
// (sum, softmax, max) from PointTerms, and its derivative dvalue_dterm against
// central differences (the max's away from ties: the largest term gets 1, the
// others 0, as max-pooling's gradient).
TEST(Aggregation, EveryPolicyGivesItsValueAndDerivative) {
  std::mt19937_64 rng(11);
  const MixtureModel models[] = {MixtureModel{.aggregation = Aggregation::kSum},
                                 MixtureModel{.aggregation = Aggregation::kSoftmax, .beta = 50.0},
                                 MixtureModel{.aggregation = Aggregation::kMax}};
  auto value = [](const std::vector<double>& g, const MixtureModel& model) {
    PointTerms<double> t = no_terms<double>();
    for (double v : g) add_term(t, v, model);
    return terms_value(t, model);
  };
  for (int trial = 0; trial < 20; ++trial) {
    const std::vector<double> g = random_terms(rng, 2 + trial % 4);
    const double largest = *std::max_element(g.begin(), g.end());
    double sum = 0;
    for (double v : g) sum += v;
    EXPECT_DOUBLE_EQ(value(g, models[0]), sum);
    EXPECT_NEAR(value(g, models[1]), softmax_online(g, 50.0), 1e-15);
    EXPECT_DOUBLE_EQ(value(g, models[2]), largest);
    for (const MixtureModel& model : models) {
      PointTerms<double> t = no_terms<double>();
      for (double v : g) add_term(t, v, model);
      const double f = terms_value(t, model);
      for (std::size_t k = 0; k < g.size(); ++k) {
        const double h = 1e-7;
        std::vector<double> up = g, down = g;
        up[k] += h;
        down[k] -= h;
        const double numeric = (value(up, model) - value(down, model)) / (2 * h);
        EXPECT_NEAR(dvalue_dterm(g[k], t, model, f), numeric, 1e-6 * std::max(1.0, std::abs(numeric)))
            << describe_aggregation(model.aggregation) << " term " << k;
      }
    }
  }
  // The max: exactly one term (the largest) carries the derivative.
  const std::vector<double> g = {0.2, 0.7, 0.4};
  PointTerms<double> t = no_terms<double>();
  for (double v : g) add_term(t, v, models[2]);
  EXPECT_EQ(dvalue_dterm(0.2, t, models[2], 0.7), 0.0);
  EXPECT_EQ(dvalue_dterm(0.7, t, models[2], 0.7), 1.0);
  EXPECT_EQ(dvalue_dterm(0.4, t, models[2], 0.7), 0.0);
  EXPECT_EQ(terms_value(no_terms<double>(), models[2]), 0.0);  // no term: 0, as the others
}

}  // namespace
}  // namespace hisnegs::gmf
