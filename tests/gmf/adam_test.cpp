// SPDX-License-Identifier: Apache-2.0
// gmf/adam: one step against the hand-computed update per parameter group, the
// bias correction over several steps against a scalar reference, the per-Gaussian
// bookkeeping (reset, keep, resize), the binary record and its refusals, and
// float against double storage.
#include "gmf/core/adam.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "io/binary_io.hpp"
#include "io/error.hpp"

namespace hisnegs::gmf {
namespace {

constexpr int P = kGaussianParamCount;

// Distinct rates per group, so a parameter updated at another group's rate shows.
const GroupRates kRates = {0.1, 0.02, 0.003, 0.4};

// The group of each of the 11 parameters, spelled out (not via group_of).
constexpr int kGroup[P] = {0, 0, 0, 1, 1, 1, 2, 2, 2, 2, 3};

std::vector<double> random_values(std::mt19937_64& rng, std::size_t n, double scale) {
  std::normal_distribution<double> d(0, scale);
  std::vector<double> v(n);
  for (double& x : v) x = d(rng);
  return v;
}

// Step 1 from zero moments: m̂ = g, v̂ = g², so θ ← θ − lr_group g / (|g| + ε).
TEST(Adam, OneStepIsTheHandComputedUpdatePerGroup) {
  std::mt19937_64 rng(101);
  const std::vector<double> p0 = random_values(rng, 2 * P, 1.0);
  const std::vector<double> g = random_values(rng, 2 * P, 0.01);
  std::vector<double> p = p0;
  Adam<double> adam({}, 2);
  adam.step(p, g, kRates);
  EXPECT_EQ(adam.steps(), 1);
  for (std::size_t i = 0; i < p.size(); ++i) {
    const double lr = kRates[kGroup[i % P]];
    EXPECT_NEAR(p[i], p0[i] - lr * g[i] / (std::abs(g[i]) + 1e-8), 1e-15) << "parameter " << i;
    EXPECT_NEAR(adam.m()[i], 0.1 * g[i], 1e-18) << "parameter " << i;
    EXPECT_NEAR(adam.v()[i], 0.001 * g[i] * g[i], 1e-20) << "parameter " << i;
  }
}

// Five steps with other β1, β2, ε against a scalar Adam written out per
// parameter, bias correction 1 − β^t included.
TEST(Adam, BiasCorrectionOverSeveralStepsMatchesAScalarReference) {
  const AdamOptions o{.beta1 = 0.8, .beta2 = 0.95, .epsilon = 1e-6};
  std::mt19937_64 rng(103);
  std::vector<double> p = random_values(rng, 3 * P, 1.0);
  std::vector<double> ref = p, m(p.size(), 0.0), v(p.size(), 0.0);
  Adam<double> adam(o, 3);
  for (int t = 1; t <= 5; ++t) {
    const std::vector<double> g = random_values(rng, p.size(), 0.1);
    adam.step(p, g, kRates);
    for (std::size_t i = 0; i < p.size(); ++i) {
      m[i] = 0.8 * m[i] + 0.2 * g[i];
      v[i] = 0.95 * v[i] + 0.05 * g[i] * g[i];
      const double m_hat = m[i] / (1 - std::pow(0.8, t)), v_hat = v[i] / (1 - std::pow(0.95, t));
      ref[i] -= kRates[kGroup[i % P]] * m_hat / (std::sqrt(v_hat) + 1e-6);
    }
    for (std::size_t i = 0; i < p.size(); ++i) ASSERT_NEAR(p[i], ref[i], 1e-14) << "step " << t << ", parameter " << i;
  }
  EXPECT_EQ(adam.steps(), 5);
}

TEST(Adam, MismatchedSizesAreRefused) {
  Adam<double> adam({}, 2);
  std::vector<double> p(2 * P), g(2 * P), short_g(2 * P - 1);
  EXPECT_THROW(adam.step(p, short_g, kRates), std::invalid_argument);
  std::vector<double> long_p(3 * P);
  EXPECT_THROW(adam.step(long_p, g, kRates), std::invalid_argument);
  EXPECT_EQ(adam.steps(), 0);
}

// An Adam of `k` Gaussians after two steps with distinct gradients (non-zero moments).
Adam<double> stepped(std::size_t k, std::mt19937_64& rng) {
  Adam<double> adam({}, k);
  std::vector<double> p = random_values(rng, k * P, 1.0);
  for (int t = 0; t < 2; ++t) adam.step(p, random_values(rng, k * P, 1.0), kRates);
  return adam;
}

TEST(Adam, ResetZeroesOnlyThatGaussiansMoments) {
  std::mt19937_64 rng(107);
  Adam<double> adam = stepped(3, rng);
  const std::vector<double> m(adam.m().begin(), adam.m().end()), v(adam.v().begin(), adam.v().end());
  adam.reset(1);
  EXPECT_EQ(adam.steps(), 2);
  for (std::size_t i = 0; i < m.size(); ++i) {
    if (i / P == 1) {
      EXPECT_EQ(adam.m()[i], 0.0) << i;
      EXPECT_EQ(adam.v()[i], 0.0) << i;
    } else {
      ASSERT_NE(m[i], 0.0);
      EXPECT_EQ(adam.m()[i], m[i]) << i;
      EXPECT_EQ(adam.v()[i], v[i]) << i;
    }
  }
}

TEST(Adam, KeepKeepsTheMomentsOfTheKeptGaussiansInOrder) {
  std::mt19937_64 rng(109);
  Adam<double> adam = stepped(5, rng);
  const std::vector<double> m(adam.m().begin(), adam.m().end()), v(adam.v().begin(), adam.v().end());
  const std::vector<std::uint32_t> kept = {0, 2, 3};
  adam.keep(kept);
  ASSERT_EQ(adam.gaussians(), 3u);
  ASSERT_EQ(adam.m().size(), 3u * P);
  ASSERT_EQ(adam.v().size(), 3u * P);
  for (std::size_t j = 0; j < kept.size(); ++j) {
    for (int i = 0; i < P; ++i) {
      EXPECT_EQ(adam.m()[j * P + i], m[kept[j] * P + i]) << "kept " << j << ", parameter " << i;
      EXPECT_EQ(adam.v()[j * P + i], v[kept[j] * P + i]) << "kept " << j << ", parameter " << i;
    }
  }
  EXPECT_EQ(adam.steps(), 2);
}

TEST(Adam, ResizeAppendsZeroMoments) {
  std::mt19937_64 rng(113);
  Adam<double> adam = stepped(2, rng);
  const std::vector<double> m(adam.m().begin(), adam.m().end()), v(adam.v().begin(), adam.v().end());
  adam.resize(4);
  ASSERT_EQ(adam.gaussians(), 4u);
  for (std::size_t i = 0; i < 4u * P; ++i) {
    EXPECT_EQ(adam.m()[i], i < m.size() ? m[i] : 0.0) << i;
    EXPECT_EQ(adam.v()[i], i < v.size() ? v[i] : 0.0) << i;
  }
  // A step over the four Gaussians works; a new one's first moment starts from 0:
  // after a step with g = 1 it is (1 − β1) g.
  std::vector<double> p(4 * P, 0.0), g(4 * P, 1.0);
  adam.step(p, g, kRates);
  EXPECT_NEAR(adam.m()[3 * P], 0.1, 1e-15);
  EXPECT_EQ(adam.steps(), 3);
}

// write_moments → read_moments restores m and v bit for bit (the caller records
// the step count): the next step of the copy equals the original's.
template <class T>
void expect_round_trip() {
  std::mt19937_64 rng(127);
  Adam<T> a({}, 3);
  std::vector<T> p(3 * P), g(3 * P);
  for (int t = 0; t < 3; ++t) {
    for (std::size_t i = 0; i < p.size(); ++i) g[i] = static_cast<T>(std::normal_distribution<double>(0, 1)(rng));
    a.step(p, g, kRates);
  }
  io::BinaryWriter w;
  a.write_moments(w);
  const std::string bytes = w.take();
  io::BinaryReader r(bytes, "run/optimizer.bin", "optimizer state");
  Adam<T> b({}, 0);
  b.read_moments(r, a.steps(), a.gaussians());
  EXPECT_TRUE(r.done());
  EXPECT_EQ(b.steps(), 3);
  EXPECT_EQ(b.gaussians(), 3u);
  EXPECT_TRUE(std::equal(a.m().begin(), a.m().end(), b.m().begin(), b.m().end()));
  EXPECT_TRUE(std::equal(a.v().begin(), a.v().end(), b.v().begin(), b.v().end()));
  std::vector<T> pa = p, pb = p;
  a.step(pa, g, kRates);
  b.step(pb, g, kRates);
  EXPECT_EQ(pa, pb);
}

TEST(Adam, MomentsRoundTripThroughABinaryRecordDouble) { expect_round_trip<double>(); }
TEST(Adam, MomentsRoundTripThroughABinaryRecordFloat) { expect_round_trip<float>(); }

// A record for another Gaussian count (in m or only in v), or a negative step
// count, is an io::InputError naming the source; the state is left as it was.
TEST(Adam, ReadingAWrongSizeOrNegativeStepIsRefused) {
  std::mt19937_64 rng(131);
  const Adam<double> a = stepped(3, rng);
  io::BinaryWriter w;
  a.write_moments(w);
  const std::string bytes = w.take();
  Adam<double> b = stepped(2, rng);
  const std::vector<double> m(b.m().begin(), b.m().end());
  for (const std::size_t k : {std::size_t{2}, std::size_t{4}}) {
    io::BinaryReader r(bytes, "run/optimizer.bin", "optimizer state");
    try {
      b.read_moments(r, 3, k);
      ADD_FAILURE() << "read " << k << " Gaussians from a record of 3";
    } catch (const io::InputError& e) {
      const std::string what = e.what();
      EXPECT_NE(what.find("run/optimizer.bin"), std::string::npos) << what;
      EXPECT_NE(what.find(std::to_string(k * P)), std::string::npos) << what;  // the expected size
    }
  }
  // m of the right size, v of another: refused after m was read, state untouched.
  {
    const std::vector<double> m_ok(2 * P, 0.5), v_short(2 * P - 1, 0.5);
    io::BinaryWriter half;
    half.put_array(std::span<const double>(m_ok));
    half.put_array(std::span<const double>(v_short));
    const std::string half_bytes = half.take();
    io::BinaryReader r(half_bytes, "run/optimizer.bin", "optimizer state");
    EXPECT_THROW(b.read_moments(r, 3, 2), io::InputError);
  }
  io::BinaryReader r(bytes, "run/optimizer.bin", "optimizer state");
  try {
    b.read_moments(r, -1, 3);
    ADD_FAILURE() << "read a negative step count";
  } catch (const io::InputError& e) {
    EXPECT_NE(std::string(e.what()).find("negative step count -1"), std::string::npos) << e.what();
  }
  EXPECT_EQ(b.steps(), 2);
  EXPECT_EQ(b.gaussians(), 2u);
  EXPECT_TRUE(std::equal(m.begin(), m.end(), b.m().begin(), b.m().end()));
}

// Float storage: each update is computed in double from the stored float values
// and rounded once, so one step gives exactly the float of the double formula;
// over ten steps float and double storage agree to float precision.
TEST(Adam, FloatStorageRoundsADoubleUpdateOnce) {
  std::mt19937_64 rng(137);
  std::vector<float> pf(2 * P), gf(2 * P);
  for (auto& x : pf) x = static_cast<float>(std::normal_distribution<double>(0, 1)(rng));
  for (auto& x : gf) x = static_cast<float>(std::normal_distribution<double>(0, 0.1)(rng));
  const std::vector<float> p0 = pf;
  Adam<float> af({}, 2);
  af.step(pf, gf, kRates);
  for (std::size_t i = 0; i < pf.size(); ++i) {
    const double g = gf[i];
    const double m = (1.0 - 0.9) * g, v = (1.0 - 0.999) * g * g;  // from zero moments
    const double expected = p0[i] - kRates[kGroup[i % P]] * (m / (1 - 0.9)) / (std::sqrt(v / (1 - 0.999)) + 1e-8);
    EXPECT_EQ(pf[i], static_cast<float>(expected)) << "parameter " << i;
    EXPECT_EQ(af.m()[i], static_cast<float>(m)) << "parameter " << i;
  }
  std::vector<double> pd(p0.begin(), p0.end());
  Adam<double> ad({}, 2);
  pf = p0;
  af.restart();
  EXPECT_EQ(af.steps(), 0);
  for (int t = 0; t < 10; ++t) {
    std::vector<double> gd(pd.size());
    for (std::size_t i = 0; i < gd.size(); ++i) {
      gf[i] = static_cast<float>(std::normal_distribution<double>(0, 0.1)(rng));
      gd[i] = gf[i];
    }
    af.step(pf, gf, kRates);
    ad.step(pd, gd, kRates);
  }
  // Ten updates of at most lr each, each rounded to float (2^-24 relative).
  for (std::size_t i = 0; i < pd.size(); ++i) EXPECT_NEAR(pf[i], pd[i], 1e-5 * (1 + std::abs(pd[i]))) << i;
}

}  // namespace
}  // namespace hisnegs::gmf
