// SPDX-License-Identifier: Apache-2.0
// Stage 2's 3D term: its value is the mean squared stage-1 residual, its gradient
// matches central differences (sum and softmax, overlapping and far Gaussians),
// it does not depend on the thread count, and with a volume the trainer prunes
// Gaussians whose centre is in empty space while a step lowers the 3D residual.
#include "splat/volume_term.hpp"

#include <gtest/gtest.h>
#include <tbb/global_control.h>

#include <cmath>
#include <random>
#include <vector>

#include "gmf/core/param_layout.hpp"
#include "splat/trainer.hpp"

namespace hisnegs::splat {
namespace {

constexpr std::size_t kParams = gmf::kGaussianParamCount;

// Three overlapping Gaussians near the origin and one far away (reaching no sample).
std::vector<float> model_params() {
  std::vector<float> p;
  const float rows[4][kParams] = {
      {0.05f, -0.02f, 0.01f, std::log(0.12f), std::log(0.08f), std::log(0.1f), 0.9f, 0.2f, -0.3f, 0.1f, 0.8f},
      {-0.06f, 0.04f, -0.03f, std::log(0.09f), std::log(0.14f), std::log(0.07f), 0.5f, -0.4f, 0.6f, 0.3f, -0.2f},
      {0.0f, 0.07f, 0.05f, std::log(0.06f), std::log(0.06f), std::log(0.11f), 1.0f, 0.0f, 0.0f, 0.0f, 0.4f},
      {5.0f, 5.0f, 5.0f, std::log(0.05f), std::log(0.05f), std::log(0.05f), 1.0f, 0.0f, 0.0f, 0.0f, 0.0f},
  };
  for (const auto& row : rows) p.insert(p.end(), row, row + kParams);
  return p;
}

// A 6³ lattice over [−0.25, 0.25]³ in blocks of 27 (2×... grouped by octant), random targets.
VolumeSamples lattice(std::uint64_t seed) {
  VolumeSamples s;
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  s.block_begin.clear();
  s.block_begin.push_back(0);
  for (int bz = 0; bz < 2; ++bz) {
    for (int by = 0; by < 2; ++by) {
      for (int bx = 0; bx < 2; ++bx) {
        for (int k = 0; k < 3; ++k) {
          for (int j = 0; j < 3; ++j) {
            for (int i = 0; i < 3; ++i) {
              s.x.push_back(static_cast<float>(-0.25 + 0.1 * (3 * bx + i)));
              s.y.push_back(static_cast<float>(-0.25 + 0.1 * (3 * by + j)));
              s.z.push_back(static_cast<float>(-0.25 + 0.1 * (3 * bz + k)));
              s.value.push_back(static_cast<float>(u(rng)));
              s.weight.push_back(static_cast<float>(bx == 1 && bz == 1 ? 3.0 : 1.0));  // some "background" weight
            }
          }
        }
        s.block_begin.push_back(static_cast<std::uint32_t>(s.value.size()));
      }
    }
  }
  return s;
}

gmf::MixtureModel softmax_model(double beta, double cutoff = 16.0) {
  return {gmf::Aggregation::kSoftmax, beta, cutoff};
}

// The term's value, recomputed independently: weight × mean over the blocks' samples of (w (f − V))².
double direct_value(const std::vector<float>& params, const VolumeSamples& s, const std::vector<std::uint32_t>& blocks,
                    const gmf::MixtureModel& model, double weight) {
  double sum = 0;
  std::size_t n = 0;
  for (std::uint32_t b : blocks) {
    for (std::uint32_t j = s.block_begin[b]; j < s.block_begin[b + 1]; ++j) {
      const double x[3] = {s.x[j], s.y[j], s.z[j]};
      gmf::PointTerms<double> t = gmf::no_terms<double>();
      for (std::size_t k = 0; k * kParams < params.size(); ++k) {
        double p[kParams];
        std::copy_n(params.data() + kParams * k, kParams, p);
        gmf::GaussianFrame<double> f;
        gmf::prepare_gaussian(p, f);
        double z[3];
        if (gmf::mahalanobis(f, x, z) > model.cutoff) continue;
        gmf::add_term(t, gmf::evaluate_gaussian<double>(f, x, nullptr), model);
      }
      const double r = s.weight[j] * (gmf::terms_value(t, model) - s.value[j]);
      sum += r * r;
      ++n;
    }
  }
  return weight * sum / static_cast<double>(n);
}

class VolumeTermGradient : public ::testing::TestWithParam<gmf::MixtureModel> {};

// The model's cutoff makes f jump by a e^{−δ/2} where a sample crosses a support
// boundary; the gradient checks use δ = 100 (a jump of e^{−50}) so central
// differences see the smooth function. The value check covers δ = 16.
TEST(VolumeTerm, ValueIsTheMeanSquaredResidualWithinTheCutoff) {
  const std::vector<std::uint32_t> blocks = {1, 2, 6};
  std::vector<float> params = model_params();
  for (const gmf::MixtureModel& model : {gmf::MixtureModel{gmf::Aggregation::kSum, 1.0, 16.0}, softmax_model(64.0),
                                         softmax_model(8.0, 4.0)}) {
    const VolumeTerm term(lattice(5), model, nullptr);
    std::vector<float> grad(params.size(), 0.0f);
    const double value = term.add(params, blocks, 2.5, grad);
    EXPECT_NEAR(value, direct_value(params, lattice(5), blocks, model, 2.5), 1e-12 * value);
  }
}

TEST_P(VolumeTermGradient, MatchesCentralDifferences) {
  const gmf::MixtureModel model = GetParam();
  const VolumeTerm term(lattice(5), model, nullptr);
  const std::vector<std::uint32_t> blocks = {0, 3, 3, 7, 5};  // repeats count twice
  std::vector<float> params = model_params();
  std::vector<float> grad(params.size(), 0.0f);
  const double weight = 0.7;
  const double value = term.add(params, blocks, weight, grad);
  EXPECT_NEAR(value, direct_value(params, lattice(5), blocks, model, weight), 1e-9 * value);
  // Central differences in double precision of the independent evaluation (float
  // parameters are stepped by h; h large enough for float's resolution).
  for (std::size_t i = 0; i < params.size(); ++i) {
    const float h = 1e-3f;
    std::vector<float> plus = params, minus = params;
    plus[i] += h;
    minus[i] -= h;
    const double fd = (direct_value(plus, lattice(5), blocks, model, weight) -
                       direct_value(minus, lattice(5), blocks, model, weight)) /
                      (static_cast<double>(plus[i]) - static_cast<double>(minus[i]));
    EXPECT_NEAR(grad[i], fd, 2e-3 * std::max(1.0, std::abs(fd))) << "parameter " << i;
  }
  // The far Gaussian reaches no sample: its gradient is exactly zero.
  for (std::size_t c = 0; c < kParams; ++c) EXPECT_EQ(grad[3 * kParams + c], 0.0f);
}

INSTANTIATE_TEST_SUITE_P(Models, VolumeTermGradient,
                         ::testing::Values(gmf::MixtureModel{gmf::Aggregation::kSum, 1.0, 100.0},
                                           softmax_model(8.0, 100.0), softmax_model(64.0, 100.0)));

TEST(VolumeTerm, SameResultForAnyThreadCount) {
  const VolumeTerm term(lattice(9), softmax_model(64.0), nullptr);
  const std::vector<std::uint32_t> blocks = {0, 1, 2, 3, 4, 5, 6, 7};
  const std::vector<float> params = model_params();
  std::vector<float> g1(params.size(), 0.0f), g2(params.size(), 0.0f);
  double v1 = 0, v2 = 0;
  {
    tbb::global_control one(tbb::global_control::max_allowed_parallelism, 1);
    v1 = term.add(params, blocks, 1.0, g1);
  }
  {
    tbb::global_control two(tbb::global_control::max_allowed_parallelism, 2);
    v2 = term.add(params, blocks, 1.0, g2);
  }
  EXPECT_EQ(v1, v2);
  EXPECT_EQ(g1, g2);
}

TEST(VolumeTerm, RefusesInconsistentSamples) {
  VolumeSamples s = lattice(1);
  s.weight.pop_back();
  EXPECT_THROW(VolumeTerm(s, softmax_model(8.0), nullptr), std::invalid_argument);
  s = lattice(1);
  s.value[3] = NAN;
  EXPECT_THROW(VolumeTerm(s, softmax_model(8.0), nullptr), std::invalid_argument);
  s = lattice(1);
  s.block_begin[2] = s.block_begin[1];  // an empty block
  EXPECT_THROW(VolumeTerm(s, softmax_model(8.0), nullptr), std::invalid_argument);
}

// A trainer with a volume: prune() drops the Gaussian whose centre is in empty
// space (x > 1 here) and keeps the others; its steps lower the 3D residual.
TEST(VolumeTerm, TrainerPrunesEmptySpaceAndFollowsTheVolume) {
  // One view of a 16x16 blank image: the image terms alone would only dim the model.
  TrainingData data;
  CameraOptions camera;
  camera.width = camera.height = 16;
  data.intrinsics = make_intrinsics(camera);
  data.views = custom_orbit(camera, {20.0}, {0.0}).views;
  data.images.assign(16 * 16, 0.0f);
  TrainOptions o;
  o.epochs = 30;
  o.lr_initial = o.lr_final = 1e-2;
  o.beta_start = o.beta_end = 50.0;
  o.beta_warmup_epochs = 0;
  o.densify_from = o.densify_until = 1000000;
  o.prune_every = 1000000;
  o.lambda_3d = 10.0;
  o.volume_blocks = 8;
  SplatSettings splat;
  splat.mode = MipMode::kSoftmax;
  Trainer trainer(o, splat, data, model_params(), make_splat_renderer(Backend::kCpu));
  auto term = std::make_shared<VolumeTerm>(lattice(2), softmax_model(64.0),
                                           [](const double w[3]) { return w[0] > 1.0; });
  const std::vector<std::uint32_t> all = {0, 1, 2, 3, 4, 5, 6, 7};
  std::vector<float> scratch(model_params().size(), 0.0f);
  const double before = term->add(model_params(), all, 1.0, scratch);
  trainer.attach_volume(term);
  for (int e = 0; e < o.epochs; ++e) (void)trainer.run_epoch();
  const std::vector<float> after_params(trainer.params().begin(), trainer.params().end());
  std::vector<float> g(after_params.size(), 0.0f);
  EXPECT_LT(term->add(after_params, all, 1.0, g), before);
  const Trainer::Pruned pruned = trainer.prune();
  EXPECT_EQ(pruned.empty, 1);
  EXPECT_EQ(pruned.total, 1);
  EXPECT_EQ(trainer.gaussians(), 3);
  for (int k = 0; k < 3; ++k) EXPECT_LT(trainer.params()[kParams * k + gmf::kMeanX], 1.0f);
}

}  // namespace
}  // namespace hisnegs::splat
