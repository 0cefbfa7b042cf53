// SPDX-License-Identifier: Apache-2.0
// gmf/psnr: the known values (identical arrays, a known MSE), refused inputs,
// and the chunked reduction against a plain sequential sum and across thread
// counts.
#include "gmf/core/psnr.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

namespace hisnegs::gmf {
namespace {

TEST(Psnr, IdenticalArraysArePlusInfinity) {
  const std::vector<float> a = {0.1f, 0.5f, 0.9f, 0.0f};
  EXPECT_EQ(mean_squared_error(a, a), 0.0);
  EXPECT_EQ(psnr(a, a), std::numeric_limits<double>::infinity());
  EXPECT_EQ(psnr_from_mse(0.0), std::numeric_limits<double>::infinity());
}

// Differences 0.5, 0, 0.25, 0 (exact in float): MSE = (0.25 + 0.0625) / 4 =
// 0.078125, PSNR = 10 log10(12.8) = 11.0721 dB; and MSE 0.01 is 20 dB.
TEST(Psnr, KnownMseGivesKnownDecibels) {
  const std::vector<float> ref = {0.0f, 0.5f, 0.75f, 1.0f};
  const std::vector<float> val = {0.5f, 0.5f, 0.5f, 1.0f};
  EXPECT_EQ(mean_squared_error(val, ref), 0.078125);
  EXPECT_NEAR(psnr(val, ref), 11.072099696478684, 1e-12);
  EXPECT_NEAR(psnr_from_mse(0.01), 20.0, 1e-12);
  EXPECT_NEAR(psnr_from_mse(1.0), 0.0, 1e-15);
}

TEST(Psnr, SizeMismatchAndEmptyArraysAreRefused) {
  const std::vector<float> three(3, 0.5f), four(4, 0.5f), none;
  EXPECT_THROW((void)mean_squared_error(three, four), std::invalid_argument);
  EXPECT_THROW((void)psnr(four, three), std::invalid_argument);
  EXPECT_THROW((void)mean_squared_error(none, none), std::invalid_argument);
  EXPECT_THROW((void)psnr(none, none), std::invalid_argument);
}

// 3 × 2^16 + 12345 values (four chunks, the last partial): the chunked sum equals
// a plain sequential double sum up to summation order (1e-12 relative), and is
// the same bit for bit with 1, 2 and 3 TBB threads.
TEST(Psnr, LongArraysMatchASequentialSumForAnyThreadCount) {
  const std::size_t n = 3 * (std::size_t{1} << 16) + 12345;
  std::mt19937_64 rng(61);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<float> a(n), b(n);
  for (std::size_t i = 0; i < n; ++i) {
    a[i] = u(rng);
    b[i] = u(rng);
  }
  double se = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double d = static_cast<double>(a[i]) - b[i];
    se += d * d;
  }
  const double reference = se / static_cast<double>(n);
  std::vector<double> mse;
  for (const int threads : {1, 2, 3}) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    mse.push_back(mean_squared_error(a, b));
  }
  EXPECT_NEAR(mse[0], reference, 1e-12 * reference);
  EXPECT_EQ(mse[1], mse[0]);
  EXPECT_EQ(mse[2], mse[0]);
  EXPECT_EQ(psnr(a, b), psnr_from_mse(mse[0]));
}

}  // namespace
}  // namespace hisnegs::gmf
