// SPDX-License-Identifier: Apache-2.0
// The stage-2 trainer on tiny scenes: ground truth rendered by the CPU splatter from a
// known mixture (8 orbit views, 32x32), the trainer started from a perturbed copy.
// Schedules, one step lowering the loss, density control keeping every per-Gaussian
// array aligned, bit-identical resume, and convergence above 35 dB.
#include "splat/trainer.hpp"
#include "splat/training_checkpoint.hpp"

#include <gtest/gtest.h>

#include <barrier>
#include <cmath>
#include <cstring>
#include <limits>
#include <numeric>
#include <random>
#include <span>
#include <stdexcept>
#include <thread>
#include <vector>

#include "io/error.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::splat {
namespace {

constexpr std::size_t kP = gmf::kGaussianParamCount;

// 5 Gaussians near the origin, σ 0.05-0.12 world units (1.5-3.5 pixels at 32x32, 25° FOV).
std::vector<float> true_params() {
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> n(0, 1);
  std::vector<float> p;
  for (int k = 0; k < 5; ++k) {
    for (int a = 0; a < 3; ++a) p.push_back(static_cast<float>(0.5 * (2 * u(rng) - 1) * (a == 2 ? 0.5 : 1.0)));
    for (int a = 0; a < 3; ++a) p.push_back(static_cast<float>(std::log(0.05 + 0.07 * u(rng))));
    double q[4] = {n(rng), n(rng), n(rng), n(rng)};
    const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (double v : q) p.push_back(static_cast<float>(v / norm));
    const double a = 0.5 + 0.4 * u(rng);
    p.push_back(static_cast<float>(std::log(a / (1 - a))));
  }
  return p;
}

// The truth moved by a seeded perturbation: means ±0.03, log-scales ±0.15, logits ±0.4.
std::vector<float> perturbed(std::vector<float> p) {
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> u(-1, 1);
  for (std::size_t i = 0; i < p.size(); ++i) {
    const std::size_t j = i % kP;
    const double amp = j < 3 ? 0.03 : (j < 6 ? 0.15 : (j == 10 ? 0.4 : 0.0));
    p[i] = static_cast<float>(p[i] + amp * u(rng));
  }
  return p;
}

SplatSettings soft_settings() {
  SplatSettings s;
  s.mode = MipMode::kSoftmax;
  s.beta = 50.0f;
  return s;
}

// 8 views (two rings of 4) of `params` rendered at β = 50 on the CPU.
TrainingData render_truth(const std::vector<float>& params) {
  CameraOptions camera;
  camera.width = camera.height = 32;
  camera.fov_deg = 25.0;
  TrainingData data;
  data.intrinsics = make_intrinsics(camera);
  const CameraSet set = custom_orbit(camera, {-20.0, 35.0}, even_azimuths(4, 10.0));
  data.views = set.views;
  auto renderer = make_splat_renderer(Backend::kCpu);
  const std::size_t n = 32 * 32;
  data.images.resize(data.views.size() * n);
  for (std::size_t i = 0; i < data.views.size(); ++i) {
    renderer->forward(params, data.intrinsics, data.views[i], soft_settings(),
                      std::span<float>(data.images).subspan(i * n, n));
  }
  return data;
}

// β fixed at the truth's 50; density control and checkpoints off unless a test turns them on.
TrainOptions quiet_options(int epochs) {
  TrainOptions o;
  o.epochs = epochs;
  o.lr_initial = 1e-2;
  o.lr_final = 1e-4;
  o.beta_start = o.beta_end = 50.0;
  o.beta_warmup_epochs = 0;
  o.densify_from = o.densify_until = 1000000;
  o.prune_every = 1000000;
  o.save_every = 1000000;
  o.seed = 3;
  return o;
}

Trainer make_trainer(const TrainOptions& o, std::vector<float> init) {
  return Trainer(o, soft_settings(), render_truth(true_params()), std::move(init), make_splat_renderer(Backend::kCpu));
}

TEST(TrainerSchedule, CosineLearningRateAndLinearBetaWarmup) {
  TrainOptions o;
  o.epochs = 101;
  o.lr_initial = 3e-3;
  o.lr_final = 1e-5;
  o.beta_start = 10;
  o.beta_end = 50;
  o.beta_warmup_epochs = 40;
  EXPECT_DOUBLE_EQ(learning_rate(o, 0), 3e-3);
  EXPECT_DOUBLE_EQ(learning_rate(o, 100), 1e-5);
  EXPECT_NEAR(learning_rate(o, 50), 0.5 * (3e-3 + 1e-5), 1e-15);  // cos(π/2) = 0: the midpoint
  EXPECT_GT(learning_rate(o, 30), learning_rate(o, 31));
  EXPECT_DOUBLE_EQ(soft_mip_beta(o, 0), 10.0);
  EXPECT_DOUBLE_EQ(soft_mip_beta(o, 20), 30.0);
  EXPECT_DOUBLE_EQ(soft_mip_beta(o, 40), 50.0);
  EXPECT_DOUBLE_EQ(soft_mip_beta(o, 90), 50.0);
  o.beta_warmup_epochs = 0;
  EXPECT_DOUBLE_EQ(soft_mip_beta(o, 0), 50.0);
}

// train.hard_share: the last share of the epochs, rounded up to whole epochs.
TEST(TrainerSchedule, TheHardShareIsTheLastEpochs) {
  TrainOptions o;
  o.epochs = 10;
  o.hard_share = 0.25;  // epochs 8 and 9 (0-based): ceil(0.75 × 10) = 8
  for (int e = 0; e < 10; ++e) EXPECT_EQ(hard_mip_epoch(o, e), e >= 8) << e;
  o.hard_share = 0.0;
  for (int e = 0; e < 10; ++e) EXPECT_FALSE(hard_mip_epoch(o, e)) << e;
}

// Epochs in the hard share train the hard MIP itself (its subgradient): they report
// β = ∞, and they raise the hard MIP's PSNR against a hard-MIP truth.
TEST(Trainer, TheHardShareTrainsTheHardMip) {
  TrainOptions o = quiet_options(6);
  o.lr_initial = 3e-3;
  o.hard_share = 0.9;  // epochs 1..5 hard
  std::vector<float> truth = true_params();
  TrainingData data = render_truth(truth);
  SplatSettings hard = soft_settings();
  hard.mode = MipMode::kMax;
  auto renderer = make_splat_renderer(Backend::kCpu);
  const std::size_t n = 32 * 32;
  for (std::size_t i = 0; i < data.views.size(); ++i) {
    renderer->forward(truth, data.intrinsics, data.views[i], hard, std::span<float>(data.images).subspan(i * n, n));
  }
  Trainer trainer(o, soft_settings(), data, perturbed(truth), make_splat_renderer(Backend::kCpu));
  const double before = trainer.evaluate(trainer.params(), 50.0, MipMode::kMax).psnr;
  const EpochReport first = trainer.run_epoch();
  EXPECT_EQ(first.beta, 50.0);
  for (int e = 1; e < 6; ++e) EXPECT_TRUE(std::isinf(trainer.run_epoch().beta)) << e;
  const double after = trainer.evaluate(trainer.params(), 50.0, MipMode::kMax).psnr;
  EXPECT_GT(after, before + 1.0) << "hard-MIP PSNR " << before << " -> " << after;
}

TEST(Trainer, OneFullBatchStepLowersTheLoss) {
  TrainOptions o = quiet_options(10);
  o.lr_initial = 1e-3;  // small enough for a first Adam step (≈ lr per parameter) to descend
  Trainer trainer = make_trainer(o, perturbed(true_params()));
  const Trainer::Evaluation before = trainer.evaluate();
  std::vector<int> all(static_cast<std::size_t>(trainer.data().count()));
  std::iota(all.begin(), all.end(), 0);
  const double step_loss = trainer.step(all);
  EXPECT_NEAR(step_loss, before.loss, 1e-9 * before.loss);  // the step saw the same objective
  const Trainer::Evaluation after = trainer.evaluate();
  EXPECT_LT(after.loss, before.loss);
  EXPECT_GT(after.psnr, before.psnr);
  EXPECT_EQ(trainer.step_count(), 1);
}

// Numerical guards: a non-finite initial value is refused naming the
// Gaussian and group; a diverging training stops with the epoch and step named.
TEST(Trainer, NonFiniteValuesStopNamingWhereTheyAre) {
  std::vector<float> init = perturbed(true_params());
  std::vector<float> bad = init;
  bad[kP * 2 + 4] = std::numeric_limits<float>::quiet_NaN();  // Gaussian 2's second log-scale
  try {
    (void)make_trainer(quiet_options(3), bad);
    FAIL() << "a NaN initial value was accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("the log-scales value of Gaussian 2 (nan) of the initial model is not finite"),
              std::string::npos)
        << e.what();
  }
  // A learning rate of 1e38 walks the parameters past the float range within a few
  // Adam steps (each moves a parameter by about lr): the step that does it stops.
  TrainOptions wild = quiet_options(3);
  wild.lr_initial = wild.lr_final = 1e38;
  Trainer trainer = make_trainer(wild, init);
  std::vector<int> all(static_cast<std::size_t>(trainer.data().count()));
  std::iota(all.begin(), all.end(), 0);
  std::string message;
  for (int i = 0; i < 10 && message.empty(); ++i) {
    try {
      (void)trainer.step(all);
    } catch (const std::runtime_error& e) {
      message = e.what();
    }
  }
  // The loss guard or the parameter guard, whichever sees it first, names epoch and step.
  EXPECT_EQ(message.rfind("training diverged", 0), 0u) << message;
  EXPECT_NE(message.find("epoch 1, step "), std::string::npos) << message;
  EXPECT_NE(message.find("not finite"), std::string::npos) << message;
}

TEST(Trainer, PruneKeepsSurvivorsAndTheirMomentsAligned) {
  std::vector<float> init = perturbed(true_params());
  init[1 * kP + 10] = -12.0f;  // Gaussian 1: a ≈ 6e-6, far below prune_intensity even after a few steps
  TrainOptions o = quiet_options(10);
  Trainer trainer = make_trainer(o, init);
  for (int i = 0; i < 3; ++i) trainer.step(std::vector<int>{i, i + 4});
  ASSERT_EQ(trainer.gaussians(), 5);
  const auto block = [](std::span<const float> s, std::size_t k) {
    return std::vector<float>(s.begin() + static_cast<std::ptrdiff_t>(k * kP),
                              s.begin() + static_cast<std::ptrdiff_t>((k + 1) * kP));
  };
  const std::vector<float> p2 = block(trainer.params(), 2), m2 = block(trainer.adam_m(), 2),
                           v2 = block(trainer.adam_v(), 2), m0 = block(trainer.adam_m(), 0);
  const double accum2 = trainer.grad_accum()[2];
  const std::uint32_t count2 = trainer.grad_count()[2];
  ASSERT_NE(m2, std::vector<float>(kP, 0.0f));  // moments are non-trivial, so the check below means something
  EXPECT_EQ(trainer.prune().total, 1);
  ASSERT_EQ(trainer.gaussians(), 4);
  EXPECT_EQ(trainer.params().size(), 4 * kP);
  EXPECT_EQ(trainer.adam_m().size(), 4 * kP);
  EXPECT_EQ(trainer.adam_v().size(), 4 * kP);
  EXPECT_EQ(trainer.grad_accum().size(), 4u);
  EXPECT_EQ(trainer.grad_count().size(), 4u);
  EXPECT_EQ(block(trainer.params(), 1), p2);  // old Gaussian 2 moved to index 1 with its state
  EXPECT_EQ(block(trainer.adam_m(), 1), m2);
  EXPECT_EQ(block(trainer.adam_v(), 1), v2);
  EXPECT_EQ(block(trainer.adam_m(), 0), m0);
  EXPECT_EQ(trainer.grad_accum()[1], accum2);
  EXPECT_EQ(trainer.grad_count()[1], count2);
}

// A trainer whose Gaussian 0 is large (split) and 1 small (clone), after two steps
// that give every Gaussian screen-gradient statistics.
Trainer densify_trainer(int max_gaussians) {
  std::vector<float> init = true_params();
  for (int a = 0; a < 3; ++a) {
    init[0 * kP + 3 + a] = std::log(0.10f);
    init[1 * kP + 3 + a] = std::log(0.04f);
  }
  init[0 * kP + 4] = std::log(0.12f);  // longest axis: 1
  TrainOptions o = quiet_options(10);
  o.densify_grad_threshold = 0.0;  // every Gaussian seen in a view is a candidate
  o.densify_scale_threshold = 0.07;
  o.max_gaussians = max_gaussians;
  Trainer trainer = make_trainer(o, init);
  for (int i = 0; i < 2; ++i) trainer.step(std::vector<int>{i, i + 2, i + 4});
  for (int k = 0; k < 5; ++k) EXPECT_GT(trainer.grad_count()[static_cast<std::size_t>(k)], 0u) << k;
  return trainer;
}

// Issue 33: after every step and every density-control epoch no Gaussian exceeds the
// axis-ratio bound, from a start of needles.
TEST(Trainer, TheAxisRatioBoundHoldsAfterEveryStepAndDensityStep) {
  TrainOptions o = quiet_options(4);
  o.densify_from = 1;
  o.densify_until = 4;
  o.densify_every = 1;
  o.densify_grad_threshold = 0.0;  // every Gaussian is a candidate
  o.prune_every = 2;
  o.max_axis_ratio = 6.0;
  std::vector<float> init = perturbed(true_params());
  for (std::size_t k = 0; k * kP < init.size(); ++k) {
    init[k * kP + gmf::kLogScale0] += 1.5f;  // a ratio of e^3 = 20 and more
    init[k * kP + gmf::kLogScale0 + 1] -= 1.5f;
  }
  Trainer trainer = make_trainer(o, init);
  while (!trainer.finished()) {
    (void)trainer.run_epoch();
    const std::span<const float> p = trainer.params();
    double worst = 0;
    for (std::size_t k = 0; k * kP < p.size(); ++k) {
      const float* s = &p[k * kP + gmf::kLogScale0];
      worst = std::max(worst, double(std::max({s[0], s[1], s[2]}) - std::min({s[0], s[1], s[2]})));
    }
    EXPECT_LE(worst, std::log(6.0) + 1e-5) << "after epoch " << trainer.epoch();
  }
}

TEST(Trainer, DensifyRespectsMaxGaussiansAndKeepsArraysAligned) {
  Trainer trainer = densify_trainer(8);  // room for 3 of the 5 candidates
  const DensifyChange change = trainer.densify();
  ASSERT_EQ(trainer.gaussians(), 8);
  EXPECT_EQ(change.split + change.cloned, 3);
  EXPECT_EQ(trainer.params().size(), 8 * kP);
  EXPECT_EQ(trainer.adam_m().size(), 8 * kP);
  EXPECT_EQ(trainer.adam_v().size(), 8 * kP);
  EXPECT_EQ(trainer.grad_accum().size(), 8u);
  EXPECT_EQ(trainer.grad_count().size(), 8u);
  for (std::size_t k = 0; k < 8; ++k) EXPECT_EQ(trainer.grad_count()[k], 0u);  // statistics reset
  for (std::size_t i = 5 * kP; i < 8 * kP; ++i) {                              // new Gaussians start with zero moments
    EXPECT_EQ(trainer.adam_m()[i], 0.0f);
    EXPECT_EQ(trainer.adam_v()[i], 0.0f);
  }
}

TEST(Trainer, DensifySplitsLargeByEq17AndClonesSmall) {
  Trainer trainer = densify_trainer(100);
  const std::vector<float> before(trainer.params().begin(), trainer.params().end());
  const std::vector<float> m_before(trainer.adam_m().begin(), trainer.adam_m().end());
  const DensifyChange change = trainer.densify();
  ASSERT_EQ(trainer.gaussians(), 10);  // all 5 densified
  const auto p = trainer.params();
  const auto m = trainer.adam_m();
  const float log08 = std::log(0.8f);
  int splits = 0;
  for (std::size_t k = 0; k < 5; ++k) {
    const float* old = before.data() + k * kP;
    const float* now = p.data() + k * kP;
    const double s_max = std::exp(static_cast<double>(std::max({old[3], old[4], old[5]})));
    // Its twin among the appended ones: the same rotation and logit.
    const float* twin = nullptr;
    for (std::size_t j = 5; j < 10; ++j) {
      const float* c = p.data() + j * kP;
      if (std::equal(c + 6, c + kP, old + 6)) twin = c;
    }
    ASSERT_NE(twin, nullptr) << k;
    if (s_max > 0.07) {
      ++splits;
      // Eq. 17: μ ± 0.5 s_max along the longest axis: midpoint μ, distance s_max; s × 0.8.
      double dist2 = 0;
      for (int a = 0; a < 3; ++a) {
        EXPECT_NEAR(0.5 * (twin[a] + now[a]), old[a], 1e-6) << k;
        dist2 += std::pow(static_cast<double>(twin[a]) - now[a], 2);
        EXPECT_NEAR(now[3 + a], old[3 + a] + log08, 1e-6) << k;
        EXPECT_EQ(twin[3 + a], now[3 + a]) << k;
      }
      EXPECT_NEAR(std::sqrt(dist2), s_max, 1e-5 * s_max) << k;
      for (std::size_t i = k * kP; i < (k + 1) * kP; ++i) EXPECT_EQ(m[i], 0.0f);  // the parent restarted
    } else {
      EXPECT_TRUE(std::equal(twin, twin + kP, old)) << k;  // a clone: an exact copy
      EXPECT_TRUE(std::equal(now, now + kP, old)) << k;
      EXPECT_TRUE(std::equal(m.begin() + static_cast<std::ptrdiff_t>(k * kP),
                             m.begin() + static_cast<std::ptrdiff_t>((k + 1) * kP),
                             m_before.begin() + static_cast<std::ptrdiff_t>(k * kP)))
          << k;  // the original keeps its moments
    }
  }
  EXPECT_EQ(change.split, splits);
  EXPECT_EQ(change.cloned, 5 - splits);
  EXPECT_GE(splits, 1);  // Gaussian 0 (s_max 0.12)
  EXPECT_LE(splits, 4);  // Gaussian 1 (0.04) is cloned
}

TEST(Trainer, ResumeIsBitIdenticalToAnUninterruptedRun) {
  TrainOptions o = quiet_options(6);
  o.views_per_step = 3;  // uneven batches (8 = 3 + 3 + 2)
  o.crop_size = 24;      // random crops draw from the RNG that resume must restore
  o.densify_from = 2;
  o.densify_until = 4;
  o.densify_every = 2;
  o.densify_grad_threshold = 0.0;
  o.max_gaussians = 9;
  o.prune_every = 3;
  o.prune_intensity = 0.6;  // prunes some of the truth's a in [0.5, 0.9]
  o.save_every = 2;
  const std::vector<float> init = perturbed(true_params());

  Trainer straight = make_trainer(o, init);
  int total_changes = 0;
  while (!straight.finished()) {
    const EpochReport r = straight.run_epoch();
    total_changes += r.split + r.cloned + r.pruned;
  }
  ASSERT_GT(total_changes, 0);  // density control ran, so its state had to be restored too

  testing::ScratchDir dir;
  {
    Trainer first = make_trainer(o, init);
    while (first.epoch() < 4) {
      first.run_epoch();
      if (first.checkpoint_due()) save_training_checkpoint(dir.path(), first, {});
    }
  }
  Trainer resumed = make_trainer(o, init);
  EXPECT_EQ(resume_training(dir.path(), resumed), 4);
  while (!resumed.finished()) resumed.run_epoch();
  ASSERT_EQ(resumed.params().size(), straight.params().size());
  EXPECT_EQ(std::memcmp(resumed.params().data(), straight.params().data(), straight.params().size_bytes()), 0);
  EXPECT_TRUE(resumed.serialize_state() == straight.serialize_state()) << "Adam, RNG or density state differs";
}

TEST(Trainer, ResumeRejectsAStateOfOtherOptions) {
  TrainOptions o = quiet_options(4);
  o.save_every = 1;
  testing::ScratchDir dir;
  {
    Trainer t = make_trainer(o, perturbed(true_params()));
    t.run_epoch();
    save_training_checkpoint(dir.path(), t, {});
  }
  o.lambda_ssim = 0.5;
  Trainer other = make_trainer(o, perturbed(true_params()));
  EXPECT_THROW(resume_training(dir.path(), other), io::InputError);
  testing::ScratchDir empty;
  EXPECT_THROW(resume_training(empty.path(), other), io::InputError);
}

// evaluate(params, β) measures any parameters at any β: the trainer's own at the
// schedule's β give evaluate(); other parameters give their own figure, and nothing
// of the trainer changes.
TEST(Trainer, EvaluatesOtherParametersAtAGivenBeta) {
  TrainOptions o = quiet_options(4);
  Trainer trainer = make_trainer(o, perturbed(true_params()));
  const std::vector<float> own(trainer.params().begin(), trainer.params().end());
  const Trainer::Evaluation now = trainer.evaluate();
  const Trainer::Evaluation same = trainer.evaluate(own, soft_mip_beta(o, 0));
  EXPECT_EQ(same.psnr, now.psnr);
  EXPECT_EQ(same.loss, now.loss);
  const std::vector<float> truth = true_params();
  const double true_psnr = trainer.evaluate(truth, soft_mip_beta(o, 0)).psnr;
  EXPECT_GT(true_psnr, now.psnr + 5.0);  // the unperturbed model renders its own views better
  EXPECT_NE(trainer.evaluate(truth, 5.0 * soft_mip_beta(o, 0)).psnr, true_psnr);
  EXPECT_EQ(std::vector<float>(trainer.params().begin(), trainer.params().end()), own);
  EXPECT_THROW((void)trainer.evaluate(std::span<const float>(truth).first(5), 10.0), std::invalid_argument);
}

TEST(Trainer, TinySceneTrainsAbove35dB) {
  TrainOptions o = quiet_options(150);
  Trainer trainer = make_trainer(o, perturbed(true_params()));
  const double start = trainer.evaluate().psnr;
  EXPECT_LT(start, 30.0);  // the perturbation is visible
  EpochReport last;
  while (!trainer.finished()) last = trainer.run_epoch();
  const double end = trainer.evaluate().psnr;
  EXPECT_GT(end, 35.0) << "from " << start << " dB; last epoch's mean " << last.psnr << " dB";
}

// Members of one process's threads summing in member order: what an MPI job's ranks
// do (apps/pipeline/distributed.hpp), without MPI. Every member must call sum()
// the same number of times with the same sizes.
class ThreadGroup {
 public:
  explicit ThreadGroup(int size) : size_(size), parts_(static_cast<std::size_t>(size)), sync_(size) {}
  class Member final : public StepGroup {
   public:
    Member(ThreadGroup& group, int rank) : group_(group), rank_(rank) {}
    [[nodiscard]] int rank() const override { return rank_; }
    [[nodiscard]] int size() const override { return group_.size_; }
    void sum(std::span<float> values) const override { group_.sum(rank_, values); }
    void sum(std::span<double> values) const override { group_.sum(rank_, values); }

   private:
    ThreadGroup& group_;
    int rank_;
  };

 private:
  template <class T>
  void sum(int rank, std::span<T> values) {
    parts_[static_cast<std::size_t>(rank)].assign(values.begin(), values.end());
    sync_.arrive_and_wait();  // every member's part is in
    for (std::size_t i = 0; i < values.size(); ++i) {
      T t = 0;
      for (const std::vector<double>& part : parts_) t = static_cast<T>(t + static_cast<T>(part[i]));
      values[i] = t;
    }
    sync_.arrive_and_wait();  // every member has read the parts
  }
  int size_;
  std::vector<std::vector<double>> parts_;
  std::barrier<> sync_;
};

TEST(Trainer, TwoMembersSharingTheStepsTrainTheModelOfOneWithinRounding) {
  TrainOptions o = quiet_options(6);
  o.views_per_step = 3;  // uneven batches (8 = 3 + 3 + 2): member 1 renders 1 view of each
  o.crop_size = 24;      // crops drawn by every member alike
  o.densify_from = 2;
  o.densify_until = 4;
  o.densify_every = 2;
  o.densify_grad_threshold = 0.0;
  o.max_gaussians = 9;  // density control decides from the summed statistics
  o.prune_every = 3;
  o.prune_intensity = 0.6;
  const std::vector<float> init = perturbed(true_params());
  Trainer alone = make_trainer(o, init);
  std::vector<EpochReport> alone_reports;
  while (!alone.finished()) alone_reports.push_back(alone.run_epoch());

  ThreadGroup group(2);
  std::vector<Trainer> members;
  for (int r = 0; r < 2; ++r) {
    members.push_back(make_trainer(o, init));
    members.back().share_steps(std::make_shared<ThreadGroup::Member>(group, r));
  }
  std::vector<std::vector<EpochReport>> reports(2);
  std::vector<Trainer::Evaluation> evaluations(2);
  {
    std::vector<std::jthread> threads;
    for (int r = 0; r < 2; ++r) {
      threads.emplace_back([&, r] {
        Trainer& t = members[static_cast<std::size_t>(r)];
        while (!t.finished()) reports[static_cast<std::size_t>(r)].push_back(t.run_epoch());
        evaluations[static_cast<std::size_t>(r)] = t.evaluate();
      });
    }
  }
  // The members hold the same bits, and the same density decisions as one process.
  ASSERT_EQ(members[0].params().size(), members[1].params().size());
  EXPECT_EQ(std::memcmp(members[0].params().data(), members[1].params().data(), members[0].params().size_bytes()), 0);
  EXPECT_TRUE(members[0].serialize_state() == members[1].serialize_state());
  ASSERT_EQ(members[0].params().size(), alone.params().size());
  int changes = 0;
  for (const EpochReport& r : alone_reports) changes += r.split + r.cloned + r.pruned;
  EXPECT_GT(changes, 0) << "density control must have run on the summed statistics";
  for (std::size_t e = 0; e < alone_reports.size(); ++e) {
    EXPECT_EQ(reports[0][e].gaussians, alone_reports[e].gaussians) << "epoch " << e + 1;
    EXPECT_NEAR(reports[0][e].loss, alone_reports[e].loss, 1e-5 * alone_reports[e].loss) << "epoch " << e + 1;
  }
  // A float sum in another order: the parameters agree to rounding grown over 6 epochs.
  double worst = 0;
  for (std::size_t i = 0; i < alone.params().size(); ++i) {
    worst = std::max(worst, std::abs(static_cast<double>(members[0].params()[i]) - alone.params()[i]));
  }
  EXPECT_LT(worst, 1e-4);
  const Trainer::Evaluation single = alone.evaluate();
  EXPECT_NEAR(evaluations[0].psnr, single.psnr, 1e-3);
  EXPECT_EQ(evaluations[0].psnr, evaluations[1].psnr);
}

}  // namespace
}  // namespace hisnegs::splat
