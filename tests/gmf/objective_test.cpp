// SPDX-License-Identifier: Apache-2.0
// gmf/objective: the first-order loss ½ Σ w² (f_δ − V)² and its gradient on the
// small known scene: the gradient against Ridders differences of the value, the
// value against a direct sum over every sample and Gaussian.
#include "gmf/objective.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <random>
#include <utility>
#include <vector>

#include "gmf/block_index.hpp"
#include "gmf/detail/block_cost.hpp"
#include "gmf/core/gaussian_math.hpp"
#include "gmf/samples.hpp"
#include "tests/gmf/gmf_test_scenes.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::gmf {
namespace {

// The mixture as the objective's flat parameter vector.
std::vector<double> flat_of(const GaussianMixture& m) {
  std::vector<double> x(kGaussianParamCount * m.size());
  for (std::size_t k = 0; k < m.size(); ++k) {
    const auto a = to_array(m[k]);
    for (int i = 0; i < kGaussianParamCount; ++i) x[kGaussianParamCount * k + i] = a[i];
  }
  return x;
}

// The scene's Gaussians with means moved by 0.4 voxel and intensity logits by 0.5
// (normal); `widened`: also scales × e^0.4 and rotations tilted, so that several
// overlap at most samples.
GaussianMixture perturbed(const Scene& scene, std::mt19937_64& rng, bool widened) {
  std::normal_distribution<double> n(0, 1);
  GaussianMixture m = scene.truth;
  for (auto& g : m) {
    for (int a = 0; a < 3; ++a) g.mean[a] += static_cast<float>(0.4 * scene.frame.voxel_size().x() * n(rng));
    if (widened) {
      for (float& s : g.log_scale) s += 0.4f;
      g.rotation = {0.9f, static_cast<float>(0.2 * n(rng)), static_cast<float>(0.2 * n(rng)), 0.1f};
    }
    g.intensity_logit += static_cast<float>(0.5 * n(rng));
  }
  return m;
}

// The sum, the softmax at a low β and at a high β with a narrower support, and the max.
const std::array<MixtureModel, 4> kBoundedModels = {
    MixtureModel{.cutoff = 16.0}, MixtureModel{.aggregation = Aggregation::kSoftmax, .beta = 8.0, .cutoff = 16.0},
    MixtureModel{.aggregation = Aggregation::kSoftmax, .beta = 64.0, .cutoff = 9.0},
    MixtureModel{.aggregation = Aggregation::kMax, .cutoff = 16.0}};

// The first-order objective's gradient is the derivative of its value.
TEST(GmfObjective, GradientMatchesItsValue) {
  const Scene scene = make_scene(13);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture m = scene.truth;
  for (auto& g : m) g.mean[0] += static_cast<float>(0.3 * scene.frame.voxel_size().x());
  const BlockIndex index = build_block_index(m, samples, scene.frame, 1e9);
  const FitObjective objective(samples, index, m.size(), MixtureModel{.cutoff = 1e9});
  std::vector<double> x(objective.parameters());
  for (std::size_t k = 0; k < m.size(); ++k) {
    const auto a = to_array(m[k]);
    for (int i = 0; i < kGaussianParamCount; ++i) x[11 * k + i] = a[i];
  }
  std::vector<double> grad(x.size());
  objective.evaluate(x.data(), grad.data());
  double largest = 0;
  for (double g : grad) largest = std::max(largest, std::abs(g));
  for (std::size_t i : {std::size_t{0}, std::size_t{4}, std::size_t{7}, std::size_t{10}, std::size_t{11 * 5 + 2},
                        std::size_t{11 * 9 + 8}, std::size_t{11 * 19 + 10}}) {
    auto f = [&](double v) {
      std::vector<double> y = x;
      y[i] = v;
      return objective.evaluate(y.data(), nullptr);
    };
    const double h0 = (i % 11) <= kMeanZ ? 0.1 * scene.frame.voxel_size().x() : 0.01;
    const double fd = testing::ridders_derivative(f, x[i], h0);
    EXPECT_NEAR(grad[i], fd, 1e-6 * std::max({std::abs(grad[i]), std::abs(fd), 1e-3 * largest})) << "parameter " << i;
  }
}

// The max-mixture's objective (the fit's hard share): its gradient, the max's
// subgradient, is the derivative of its value away from ties. Central differences
// with a step of 1e-6 (no sample's two largest terms are that close), on Gaussians
// widened so that several overlap at most samples.
TEST(GmfObjective, MaxGradientMatchesItsValueAwayFromTies) {
  const Scene scene = make_scene(13);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  std::mt19937_64 rng(14);
  const GaussianMixture m = perturbed(scene, rng, true);
  const MixtureModel model{.aggregation = Aggregation::kMax, .cutoff = 1e9};
  const BlockIndex index = build_block_index(m, samples, scene.frame, model.cutoff);
  const FitObjective objective(samples, index, m.size(), model);
  const std::vector<double> x = flat_of(m);
  std::vector<double> grad(x.size());
  objective.evaluate(x.data(), grad.data());
  double largest = 0;
  for (double g : grad) largest = std::max(largest, std::abs(g));
  ASSERT_GT(largest, 0.0);
  int moved = 0;
  for (std::size_t i = 0; i < x.size(); i += 3) {
    auto f = [&](double v) {
      std::vector<double> y = x;
      y[i] = v;
      return objective.evaluate(y.data(), nullptr);
    };
    const double h = 1e-6;
    const double fd = (f(x[i] + h) - f(x[i] - h)) / (2 * h);
    EXPECT_NEAR(grad[i], fd, 1e-4 * std::max({std::abs(grad[i]), std::abs(fd), 1e-3 * largest})) << "parameter " << i;
    moved += grad[i] != 0.0 ? 1 : 0;
  }
  EXPECT_GT(moved, static_cast<int>(x.size() / 6)) << "most Gaussians are the max somewhere";
}

// sample_residuals: ½ Σ r² is the objective's value and Jᵀ r its gradient, for both
// aggregations; a Jacobian column is the Ridders derivative of the residuals.
TEST(GmfObjective, SampleResidualsAndTheirJacobianAreTheSameProblem) {
  const Scene scene = make_scene(13);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture m = scene.truth;
  for (auto& g : m) g.mean[1] += static_cast<float>(0.2 * scene.frame.voxel_size().y());
  for (const MixtureModel model : {MixtureModel{.cutoff = 1e9},
                                   MixtureModel{.aggregation = Aggregation::kSoftmax, .beta = 20, .cutoff = 1e9}}) {
    const BlockIndex index = build_block_index(m, samples, scene.frame, model.cutoff);
    const FitObjective objective(samples, index, m.size(), model);
    const std::vector<double> x = flat_of(m);
    std::vector<double> grad(x.size());
    const double value = objective.evaluate(x.data(), grad.data());
    const SampleResiduals r = sample_residuals(samples, index, model, x.data(), true);
    ASSERT_EQ(r.residuals.size(), samples.size());
    ASSERT_EQ(r.row_begin.size(), samples.size() + 1);
    ASSERT_EQ(static_cast<std::size_t>(r.row_begin.back()), r.values.size());
    double half = 0;
    for (double v : r.residuals) half += 0.5 * v * v;
    EXPECT_NEAR(half, value, 1e-10 * value);
    std::vector<double> jtr(x.size(), 0.0);
    for (std::size_t j = 0; j < samples.size(); ++j) {
      for (auto e = r.row_begin[j]; e < r.row_begin[j + 1]; ++e) {
        jtr[static_cast<std::size_t>(r.columns[static_cast<std::size_t>(e)])] +=
            r.values[static_cast<std::size_t>(e)] * r.residuals[j];
      }
    }
    double largest = 0;
    for (double g : grad) largest = std::max(largest, std::abs(g));
    for (std::size_t i = 0; i < x.size(); ++i) EXPECT_NEAR(jtr[i], grad[i], 1e-9 * largest) << "parameter " << i;
    // Column 11·5 + 1 (a mean's y) against Ridders differences, in the 4 samples
    // where it is largest.
    const std::size_t column = 11 * 5 + 1;
    std::vector<std::pair<double, std::size_t>> entries;  // (|∂r_j/∂x|, j)
    std::vector<double> of_sample(samples.size(), 0.0);
    for (std::size_t j = 0; j < samples.size(); ++j) {
      for (auto e = r.row_begin[j]; e < r.row_begin[j + 1]; ++e) {
        if (static_cast<std::size_t>(r.columns[static_cast<std::size_t>(e)]) == column) {
          of_sample[j] = r.values[static_cast<std::size_t>(e)];
        }
      }
      entries.emplace_back(std::abs(of_sample[j]), j);
    }
    std::partial_sort(entries.begin(), entries.begin() + 4, entries.end(), std::greater<>());
    ASSERT_GT(entries[0].first, 0.0);
    for (int pick = 0; pick < 4; ++pick) {
      const std::size_t j = entries[static_cast<std::size_t>(pick)].second;
      const double analytic = of_sample[j];
      const auto f = [&](double v) {
        std::vector<double> y = x;
        y[column] = v;
        return sample_residuals(samples, index, model, y.data(), false).residuals[j];
      };
      const double fd = testing::ridders_derivative(f, x[column], 0.1 * scene.frame.voxel_size().y());
      EXPECT_NEAR(analytic, fd, 1e-6 * std::max(1.0, std::abs(fd))) << "sample " << j;
    }
  }
}

// The loss is ½ Σ_j w_j² (f_δ(x_j) − V_j)² with f_δ(x) the sum over ALL Gaussians
// with m(x) <= δ, summed here sample by sample with no block index: the index
// (cut at the same δ) must list every Gaussian that reaches a sample, and
// constant() must be the part of the samples no Gaussian reaches.
TEST(GmfObjective, LossIsHalfTheWeightedSquaredResidualSum) {
  const Scene scene = make_scene(23);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  const SampleSet samples = extract_samples(grid, 3.0, 4);  // background weight sqrt(3 / 0.05) ≠ 1
  std::mt19937_64 rng(24);
  std::normal_distribution<double> n(0, 1);
  GaussianMixture m = scene.truth;
  for (auto& g : m) {
    for (int a = 0; a < 3; ++a) g.mean[a] += static_cast<float>(0.5 * scene.frame.voxel_size().x() * n(rng));
    g.intensity_logit += static_cast<float>(0.3 * n(rng));
  }
  constexpr double kCutoff = 16.0;
  const BlockIndex index = build_block_index(m, samples, scene.frame, kCutoff);
  const FitObjective objective(samples, index, m.size(), MixtureModel{.cutoff = kCutoff});
  const std::vector<double> x = flat_of(m);
  const double loss = objective.evaluate(x.data(), nullptr);

  std::vector<GaussianFrame<double>> frames;
  for (const auto& g : m) frames.push_back(frame_of(g));
  double direct = 0, unreached = 0;
  for (std::size_t b = 0; b < samples.blocks(); ++b) {
    for (std::uint32_t s = samples.block_begin[b]; s < samples.block_begin[b + 1]; ++s) {
      const double p[3] = {samples.x[s], samples.y[s], samples.z[s]};
      double f = 0;
      for (const auto& fr : frames) {
        double z[3];
        if (mahalanobis(fr, p, z) <= kCutoff) f += evaluate_gaussian<double>(fr, p, nullptr);
      }
      const double r = samples.weight[s] * (f - samples.value[s]);
      direct += 0.5 * r * r;
      if (index.of(b).empty()) unreached += 0.5 * r * r;
    }
  }
  ASSERT_GT(samples.background, 0);
  EXPECT_GT(objective.constant(), 0.0);  // some background blocks lie beyond every support
  EXPECT_NEAR(objective.constant(), unreached, 1e-12 * unreached);
  // Only the summation order differs.
  EXPECT_NEAR(loss, direct, 1e-12 * direct);
  std::vector<double> grad(x.size());
  EXPECT_EQ(objective.evaluate(x.data(), grad.data()), loss);  // the gradient pass reports the same loss
}

// The fused gradient (per-Gaussian sums chained through the rotation and sigmoid
// VJPs once) equals Jᵀr formed from BlockCost's per-sample analytic Jacobian, the
// one the least-squares solvers use, for the sum and the softmax at low and high
// β, with Gaussians widened so that several overlap at most samples; and on the
// softmax its loss equals BlockCost's residuals' ½ Σ r².
TEST(GmfObjective, FusedGradientEqualsBlockCostJacobianTimesResidual) {
  const Scene scene = make_scene(31);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  const SampleSet samples = extract_samples(grid, 2.0, 2);
  std::mt19937_64 rng(32);
  const GaussianMixture m = perturbed(scene, rng, true);
  const std::vector<double> x = flat_of(m);
  for (const MixtureModel& model : kBoundedModels) {
    const BlockIndex index = build_block_index(m, samples, scene.frame, model.cutoff);
    const FitObjective objective(samples, index, m.size(), model);
    std::vector<double> grad(x.size());
    const double loss = objective.evaluate(x.data(), grad.data());
    // Jᵀr and ½ Σ r² from BlockCost, block by block.
    std::vector<double> expected(x.size(), 0.0);
    double expected_loss = objective.constant();
    std::size_t overlapping = 0;
    for (std::size_t b = 0; b < samples.blocks(); ++b) {
      const auto ids = index.of(b);
      if (ids.empty()) continue;
      overlapping += ids.size() > 1 ? 1 : 0;
      const detail::BlockCost cost(samples, b, ids.size(), model);
      const int nr = cost.num_residuals();
      std::vector<const double*> p;
      for (std::uint32_t k : ids) p.push_back(x.data() + kGaussianParamCount * k);
      std::vector<double> r(nr);
      std::vector<std::vector<double>> J(ids.size(), std::vector<double>(nr * kGaussianParamCount));
      std::vector<double*> jp;
      for (auto& j : J) jp.push_back(j.data());
      ASSERT_TRUE(cost.Evaluate(p.data(), r.data(), jp.data()));
      for (int j = 0; j < nr; ++j) expected_loss += 0.5 * r[j] * r[j];
      for (std::size_t g = 0; g < ids.size(); ++g) {
        for (int j = 0; j < nr; ++j) {
          for (int c = 0; c < kGaussianParamCount; ++c) {
            expected[kGaussianParamCount * ids[g] + c] += r[j] * J[g][j * kGaussianParamCount + c];
          }
        }
      }
    }
    EXPECT_GT(overlapping, samples.blocks() / 4) << "the case must overlap";
    EXPECT_NEAR(loss, expected_loss, 1e-11 * expected_loss) << "beta " << model.beta;
    double largest = 0;
    for (double g : expected) largest = std::max(largest, std::abs(g));
    ASSERT_GT(largest, 0.0);
    for (std::size_t i = 0; i < x.size(); ++i) {
      ASSERT_NEAR(grad[i], expected[i], 1e-9 * largest) << "parameter " << i << ", beta " << model.beta;
    }
  }
}

// hold_fixed: with half the Gaussians held, the value and foreground error equal
// the whole objective's (the held parameters are not read again) and the free
// Gaussians' gradient equals its share of the whole gradient, the held ones' is 0;
// for the sum and the softmax, with the blocks only held Gaussians reach moved
// into the constant. With an unbounded support (no term leaves as a Gaussian
// moves) the gradient is also the Ridders derivative of the held value.
TEST(GmfObjective, HoldingGaussiansFixedKeepsTheValueAndTheFreeGradient) {
  const Scene scene = make_scene(37);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  const SampleSet samples = extract_samples(grid, 2.0, 2);
  std::mt19937_64 rng(38);
  std::normal_distribution<double> n(0, 1);
  const GaussianMixture m = perturbed(scene, rng, false);
  const std::vector<double> x = flat_of(m);
  const std::size_t frozen = m.size() / 2, held_params = kGaussianParamCount * frozen;
  std::vector<MixtureModel> models(kBoundedModels.begin(), kBoundedModels.end());
  models.push_back(MixtureModel{.cutoff = 1e9});
  models.push_back(MixtureModel{.aggregation = Aggregation::kSoftmax, .beta = 8.0, .cutoff = 1e9});
  for (const MixtureModel& model : models) {
    SCOPED_TRACE(::testing::Message() << "beta " << model.beta << ", cutoff " << model.cutoff);
    const bool bounded = model.cutoff < 100;
    const BlockIndex index = build_block_index(m, samples, scene.frame, model.cutoff);
    const FitObjective whole(samples, index, m.size(), model);
    FitObjective held(samples, index, m.size(), model);
    held.hold_fixed(x.data(), frozen);
    EXPECT_EQ(held.held(), frozen);
    if (bounded) {
      EXPECT_GT(held.constant(), whole.constant()) << "some blocks are reached by held Gaussians alone";
    }
    // The free Gaussians moved; the held entries of z are not read (NaN).
    std::vector<double> y = x;
    for (std::size_t i = held_params; i < y.size(); ++i) y[i] += 0.02 * n(rng);
    std::vector<double> z = y;
    std::fill_n(z.begin(), held_params, std::nan(""));
    std::vector<double> gw(x.size()), gh(x.size());
    double fg_whole = 0, fg_held = 0;
    const double lw = whole.evaluate(y.data(), gw.data(), &fg_whole);
    const double lh = held.evaluate(z.data(), gh.data(), &fg_held);
    EXPECT_NEAR(lh, lw, 1e-11 * lw);
    EXPECT_NEAR(fg_held, fg_whole, 1e-11 * fg_whole);
    double largest = 0;
    for (double g : gw) largest = std::max(largest, std::abs(g));
    ASSERT_GT(largest, 0.0);
    for (std::size_t i = 0; i < x.size(); ++i) {
      ASSERT_NEAR(gh[i], i < held_params ? 0.0 : gw[i], 1e-9 * largest) << "parameter " << i;
    }
    if (bounded) continue;
    for (std::size_t i : {held_params, held_params + 5, held_params + 2 * kGaussianParamCount + kLogit, y.size() - 3}) {
      auto f = [&](double v) {
        std::vector<double> w = z;
        w[i] = v;
        return held.evaluate(w.data(), nullptr);
      };
      const double h0 = (i % kGaussianParamCount) <= kMeanZ ? 0.1 * scene.frame.voxel_size().x() : 0.01;
      const double fd = testing::ridders_derivative(f, z[i], h0);
      EXPECT_NEAR(gh[i], fd, 1e-6 * std::max({std::abs(gh[i]), std::abs(fd), 1e-3 * largest})) << "parameter " << i;
    }
  }
}

// Evaluation does not depend on the thread count: the loss and gradient with one
// TBB thread equal those with two bit for bit (fixed chunks combined in order).
TEST(GmfObjective, ValueAndGradientAreIdenticalForOneAndTwoThreads) {
  const Scene scene = make_scene(29);
  const io::SparseGrid grid = grid_of(scene, 0.02);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture m = scene.truth;
  for (auto& g : m) g.log_scale[0] += 0.2f;
  const BlockIndex index = build_block_index(m, samples, scene.frame, 16.0);
  const FitObjective objective(samples, index, m.size(), MixtureModel{});
  const std::vector<double> x = flat_of(m);
  auto run = [&](int threads, std::vector<double>& grad) {
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, threads);
    grad.assign(x.size(), 0.0);
    return objective.evaluate(x.data(), grad.data());
  };
  std::vector<double> g1;
  const double l1 = run(1, g1);
  EXPECT_GT(l1, objective.constant());
  // Scheduling varies from run to run: three runs on two threads.
  for (int repeat = 0; repeat < 3; ++repeat) {
    std::vector<double> g2;
    EXPECT_EQ(run(2, g2), l1);
    EXPECT_EQ(g2, g1);
  }
}

}  // namespace
}  // namespace hisnegs::gmf
