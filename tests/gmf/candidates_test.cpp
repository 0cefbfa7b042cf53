// SPDX-License-Identifier: Apache-2.0
// gmf/detail/candidates: the SIMD kernels of the objective's hot loop against the
// scalar math of gaussian_math.hpp, on random anisotropic, rotated Gaussians
// (counts that are and are not multiples of the SIMD width).
#include "gmf/detail/candidates.hpp"

#include <gtest/gtest.h>

#include <cmath>
#include <numeric>
#include <random>
#include <vector>

#include "gmf/core/gaussian_math.hpp"

namespace hisnegs::gmf::detail {
namespace {

struct Candidates {
  std::vector<GaussianFrame<double>> frames;
  std::vector<double> rows;  // kGaussianRow per Gaussian, as the objective lays them out
};

Candidates random_candidates(std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> pos(-0.1, 0.1), log_s(std::log(0.003), std::log(0.05)), unit(-1, 1);
  Candidates c;
  c.frames.resize(n);
  c.rows.assign(n * kGaussianRow, 0.0);
  for (std::size_t k = 0; k < n; ++k) {
    double p[kGaussianParamCount];
    p[kMeanX] = pos(rng), p[kMeanY] = pos(rng), p[kMeanZ] = pos(rng);
    p[kLogScale0] = log_s(rng), p[kLogScale0 + 1] = log_s(rng), p[kLogScale0 + 2] = log_s(rng);
    p[kRotW] = unit(rng) + 1.5, p[kRotW + 1] = unit(rng), p[kRotW + 2] = unit(rng), p[kRotW + 3] = unit(rng);
    p[kLogit] = unit(rng);
    prepare_gaussian(p, c.frames[k]);
    write_candidate_row(c.frames[k], c.rows.data() + k * kGaussianRow);
  }
  return c;
}

CandidatePack pack_of(const Candidates& c) {
  std::vector<std::uint32_t> ids(c.frames.size());
  std::iota(ids.begin(), ids.end(), 0u);
  CandidatePack pack;
  pack.assign(c.rows.data(), ids.data(), ids.size());
  return pack;
}

TEST(GmfCandidates, DistancesEqualTheScalarMahalanobis) {
  for (const std::size_t n : {1u, 7u, 32u, 45u}) {
    const Candidates c = random_candidates(n, n);
    const CandidatePack pack = pack_of(c);
    std::vector<double> m(pack.stride), e(pack.stride), z(3 * pack.stride);
    std::mt19937_64 rng(99);
    std::uniform_real_distribution<double> pos(-0.12, 0.12);
    for (int trial = 0; trial < 20; ++trial) {
      const double x[3] = {pos(rng), pos(rng), pos(rng)};
      candidate_distances(pack, x, m.data(), e.data(), z.data());
      for (std::size_t i = 0; i < n; ++i) {
        double zs[3];
        const double expected = mahalanobis(c.frames[i], x, zs);
        ASSERT_NEAR(m[i], expected, 1e-12 * (1 + expected)) << "n " << n << ", candidate " << i;
        ASSERT_NEAR(e[i], std::exp(-0.5 * expected), 1e-13 * (1 + e[i])) << "n " << n << ", candidate " << i;
        for (int j = 0; j < 3; ++j) {
          ASSERT_NEAR(z[j * pack.stride + i], zs[j], 1e-12 * (1 + std::abs(zs[j]))) << "axis " << j;
        }
      }
    }
  }
}

// The slack is a lower bound of √m − reach over the ball: a candidate it drops
// (slack > 0) reaches no point of the ball, while one touching the ball is kept.
TEST(GmfCandidates, SlackNeverDropsACandidateThatReachesTheBall) {
  const std::size_t n = 200;
  const Candidates c = random_candidates(n, 5);
  std::vector<std::int64_t> offset((n + kCandidateAlign - 1) / kCandidateAlign * kCandidateAlign, 0);
  for (std::size_t i = 0; i < n; ++i) offset[i] = static_cast<std::int64_t>(i * kGaussianRow);
  std::vector<double> slack(offset.size());
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> pos(-0.1, 0.1), unit(-1, 1);
  const double cutoff = 16, reach = std::sqrt(cutoff);
  int dropped = 0, kept = 0;
  for (int trial = 0; trial < 20; ++trial) {
    const double centre[3] = {pos(rng), pos(rng), pos(rng)}, radius = 0.004;
    candidate_slack(c.rows.data(), offset.data(), n, centre, radius, reach, slack.data());
    for (std::size_t i = 0; i < n; ++i) {
      bool reaches = false;
      for (int p = 0; p < 200 && !reaches; ++p) {  // points in the ball, the centre first
        double d[3] = {unit(rng), unit(rng), unit(rng)};
        const double len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
        const double scale = p == 0 ? 0.0 : radius / len;
        const double x[3] = {centre[0] + d[0] * scale, centre[1] + d[1] * scale, centre[2] + d[2] * scale};
        double z[3];
        reaches = mahalanobis(c.frames[i], x, z) <= cutoff;
      }
      if (reaches) {
        ASSERT_LE(slack[i], 0.0) << "candidate " << i << " reaches the ball but was dropped";
      }
      (slack[i] > 0 ? dropped : kept) += 1;
    }
  }
  EXPECT_GT(dropped, 0) << "the case must drop some candidates";
  EXPECT_GT(kept, 0) << "the case must keep some candidates";
}

TEST(GmfCandidates, ShiftedExpEqualsStdExp) {
  const std::size_t n = 37;
  std::vector<double> v(64), out(64);
  for (std::size_t i = 0; i < n; ++i) v[i] = 0.03 * static_cast<double>(i) - 0.5;
  shifted_exp(v.data(), n, 64.0, 0.58, out.data());
  for (std::size_t i = 0; i < n; ++i) {
    const double expected = std::exp(64.0 * (v[i] - 0.58));
    ASSERT_NEAR(out[i], expected, 1e-14 * expected) << i;
  }
}

}  // namespace
}  // namespace hisnegs::gmf::detail
