// The GMF fit end to end on small synthetic data: a volume rendered from 20
// known Gaussians is fitted from a perturbed start and the Gaussians come back;
// grid initialization respects the budget; rasterization matches evaluation.
#include "gmf/fit.hpp"

#include <gtest/gtest.h>

#include <random>

#include "gmf/gaussian_math.hpp"
#include "gmf/brick_index.hpp"
#include "gmf/density.hpp"
#include "gmf/init.hpp"
#include "gmf/psnr.hpp"
#include "gmf/rasterize.hpp"
#include "gmf/objective.hpp"
#include "gmf/samples.hpp"
#include "tests/test_support.hpp"
#include "io/error.hpp"

namespace hisnegs::gmf {
namespace {

struct Scene {
  io::Volume volume;
  io::WorldFrame frame;
  GaussianMixture truth;
};

// 20 Gaussians with σ of 1.2-2 voxels, spread so that few overlap, rendered into a 48x48x24 volume.
Scene make_scene(std::uint64_t seed) {
  Scene s;
  s.volume.nx = 48;
  s.volume.ny = 48;
  s.volume.nz = 24;
  s.volume.source = "scene";
  s.frame = io::WorldFrame(48, 48, 24, Eigen::Vector3d(1.0, 1.0, 0.5));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  const double voxel = s.frame.voxel_size().x();
  while (s.truth.size() < 20) {
    GaussianParams g;
    const Eigen::Vector3d ijk(6 + 36 * u(rng), 6 + 36 * u(rng), 5 + 14 * u(rng));
    const Eigen::Vector3d p = s.frame.world_from_index(ijk);
    bool close = false;
    for (const auto& t : s.truth) {
      close |= (Eigen::Vector3d(t.mean[0], t.mean[1], t.mean[2]) - p).norm() < 7 * voxel;
    }
    if (close) continue;
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(p[a]);
    for (int a = 0; a < 3; ++a) g.log_scale[a] = static_cast<float>(std::log((1.2 + 0.8 * u(rng)) * voxel));
    std::normal_distribution<double> gauss(0, 1);
    Eigen::Vector4d q(gauss(rng), gauss(rng), gauss(rng), gauss(rng));  // uniform random rotation
    q.normalize();
    g.rotation = {static_cast<float>(q[0]), static_cast<float>(q[1]), static_cast<float>(q[2]), static_cast<float>(q[3])};
    const double a = 0.4 + 0.5 * u(rng);
    g.intensity_logit = static_cast<float>(std::log(a / (1 - a)));
    s.truth.push_back(g);
  }
  s.volume.voxels = rasterize_mixture(s.truth, s.frame, {.cutoff = 1e9});
  s.volume.normalization.method = io::NormalizationMethod::kMinMax;
  return s;
}

// The scene's sparse grid: threshold 0.02, band 2, optional background samples.
io::SparseGrid grid_of(const Scene& scene, double background_fraction) {
  io::SparseGridOptions so;
  so.threshold = 0.02;
  so.background_fraction = background_fraction;
  return io::build_sparse_grid(scene.volume, scene.frame.aspect(), so);
}

Eigen::Matrix3d covariance_of(const GaussianParams& g) {
  return covariance(g);
}

TEST(GmfFit, RecoversAKnownMixtureFromAPerturbedStart) {
  const Scene scene = make_scene(7);
  const io::SparseGrid grid = grid_of(scene, 0.01);
  std::mt19937_64 rng(9);
  std::normal_distribution<double> n(0, 1);
  GaussianMixture start = scene.truth;
  const double voxel = scene.frame.voxel_size().x();
  for (std::size_t k = 0; k < start.size(); ++k) {
    for (int a = 0; a < 3; ++a) start[k].mean[a] += static_cast<float>(0.4 * voxel * n(rng));
    for (int a = 0; a < 3; ++a) start[k].log_scale[a] += static_cast<float>(0.15 * n(rng));
    start[k].intensity_logit += static_cast<float>(0.3 * n(rng));
  }
  GmfOptions o;
  o.rounds = 2;
  o.iterations_per_round = 40;
  o.time_budget_s = 60;
  o.prune_intensity = 0.0;
  o.densify = false;  // this test is about the solver recovering known parameters
  GaussianMixture fitted = start;
  const FitResult r = fit_mixture(scene.volume, grid, fitted, o);
  ASSERT_EQ(fitted.size(), scene.truth.size());
  EXPECT_GT(r.final_psnr_3d, 50.0) << r.stop_reason;
  EXPECT_LT(r.log.back().loss, r.log.front().loss);
  for (std::size_t k = 0; k < fitted.size(); ++k) {
    const auto& t = scene.truth[k];
    const auto& f = fitted[k];
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(f.mean[a], t.mean[a], 0.02 * voxel) << "gaussian " << k;
    EXPECT_NEAR(intensity(f), intensity(t), 0.01) << "gaussian " << k;
    // Covariances (rotation is not identifiable for near-isotropic Gaussians).
    const Eigen::Matrix3d d = covariance_of(f) - covariance_of(t);
    EXPECT_LT(d.norm() / covariance_of(t).norm(), 0.02) << "gaussian " << k;
  }
}

// Every optimizer lowers the loss on the known scene from the same perturbed start.
TEST(GmfFit, EveryOptimizerLowersTheLoss) {
  const Scene scene = make_scene(11);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  std::mt19937_64 rng(12);
  std::normal_distribution<double> n(0, 1);
  GaussianMixture start = scene.truth;
  const double voxel = scene.frame.voxel_size().x();
  for (auto& g : start) {
    for (int a = 0; a < 3; ++a) g.mean[a] += static_cast<float>(0.5 * voxel * n(rng));
    g.intensity_logit += static_cast<float>(0.5 * n(rng));
  }
  for (const Optimizer opt : {Optimizer::kLevenbergMarquardt, Optimizer::kLevenbergMarquardtCgnr, Optimizer::kDogleg,
                              Optimizer::kLbfgs, Optimizer::kAdam}) {
    GmfOptions o;
    o.optimizer = opt;
    o.rounds = 1;
    o.iterations_per_round = opt == Optimizer::kAdam ? 60 : 15;
    o.prune_intensity = 0.0;
    GaussianMixture m = start;
    const FitResult r = fit_mixture(scene.volume, grid, m, o);
    ASSERT_GE(r.log.size(), 2u);
    EXPECT_LT(r.log.back().loss, 0.5 * r.log.front().loss) << static_cast<int>(opt) << " " << r.stop_reason;
  }
}

// gmf.max_iterations caps the solver iterations over all rounds, and
// gmf.stop_loss ends the fit at the first logged loss at or below it.
TEST(GmfFit, IterationCapAndStopLoss) {
  const Scene scene = make_scene(11);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  GaussianMixture start = scene.truth;
  for (auto& g : start) g.intensity_logit += 0.7f;
  for (const Optimizer opt : {Optimizer::kLevenbergMarquardtCgnr, Optimizer::kAdam}) {
    GmfOptions o;
    o.optimizer = opt;
    o.densify = false;
    o.rounds = 10;
    o.iterations_per_round = 4;
    o.max_iterations = 7;
    o.prune_intensity = 0.0;
    GaussianMixture m = start;
    const FitResult capped = fit_mixture(scene.volume, grid, m, o);
    EXPECT_EQ(capped.log.back().iteration, 7) << capped.stop_reason;
    EXPECT_EQ(capped.rounds.size(), 2u);
    EXPECT_GE(capped.measuring_seconds, 0.0);

    // Stop at a loss between the start and the end of the capped run.
    o.max_iterations = 0;
    o.stop_loss = 0.5 * (capped.log.front().loss + capped.log.back().loss);
    m = start;
    const FitResult stopped = fit_mixture(scene.volume, grid, m, o);
    EXPECT_EQ(stopped.stop_reason, "reached gmf.stop_loss");
    EXPECT_LE(stopped.log.back().iteration, 7);
    int at_or_below = 0;
    for (const FitIteration& it : stopped.log) at_or_below += it.loss <= o.stop_loss ? 1 : 0;
    EXPECT_GE(at_or_below, 1);
  }
}

// The first-order objective's gradient is the derivative of its value.
TEST(GmfObjective, GradientMatchesItsValue) {
  const Scene scene = make_scene(13);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture m = scene.truth;
  for (auto& g : m) g.mean[0] += static_cast<float>(0.3 * scene.frame.voxel_size().x());
  const BrickIndex index = build_brick_index(m, samples, scene.frame, 1e9);
  const FitObjective objective(samples, index, m.size(), 1e9);
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

TEST(GmfDensity, ClonesWhereAGaussianIsMissing) {
  const Scene scene = make_scene(17);
  const io::SparseGrid grid = grid_of(scene, 0.01);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture m;
  for (std::size_t k = 0; k < scene.truth.size(); ++k) {
    if (k != 3) m.push_back(scene.truth[k]);
  }
  GmfOptions o;
  o.densify_fraction = 0.06;  // one clone and one split at most for K = 19
  const BrickIndex index = build_brick_index(m, samples, scene.frame, o.mahalanobis_cutoff);
  const DensityChange change = adapt_density(m, samples, index, scene.frame, o);
  ASSERT_EQ(change.cloned, 1);
  const auto& clone = m[m.size() - 1];
  const auto& missing = scene.truth[3];
  const Eigen::Vector3d d(clone.mean[0] - missing.mean[0], clone.mean[1] - missing.mean[1], clone.mean[2] - missing.mean[2]);
  EXPECT_LT(d.norm(), 1.5 * scene.frame.voxel_size().maxCoeff());  // at the strongest under-covered voxel
}

TEST(GmfDensity, SplitsAnOverwideGaussianByEq17) {
  const Scene scene = make_scene(19);
  const io::SparseGrid grid = grid_of(scene, 0.01);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture m = scene.truth;
  m[0].log_scale[1] += static_cast<float>(std::log(3.0));  // axis 1 three times too wide
  const GaussianParams before = m[0];
  GmfOptions o;
  o.clone_residual = 0.99;  // splits only
  const BrickIndex index = build_brick_index(m, samples, scene.frame, o.mahalanobis_cutoff);
  const DensityChange change = adapt_density(m, samples, index, scene.frame, o);
  ASSERT_EQ(change.split, 1);
  ASSERT_EQ(m.size(), scene.truth.size() + 1);
  // Eq. 17: scales × 0.8, means ± 0.5 s_max along the longest axis (column 1 of R).
  const Eigen::Matrix3d R = rotation_matrix(before);
  const double s_max = std::exp(static_cast<double>(before.log_scale[1]));
  const GaussianParams& a = m[0];
  const GaussianParams& b = m[m.size() - 1];
  for (int r = 0; r < 3; ++r) {
    EXPECT_NEAR(a.mean[r], before.mean[r] + 0.5 * s_max * R(r, 1), 1e-6);
    EXPECT_NEAR(b.mean[r], before.mean[r] - 0.5 * s_max * R(r, 1), 1e-6);
    EXPECT_NEAR(a.log_scale[r], before.log_scale[r] + std::log(0.8), 1e-6);
    EXPECT_EQ(b.log_scale[r], a.log_scale[r]);
  }
}

TEST(GmfInit, MeetsTheBudgetOnTheForeground) {
  const Scene scene = make_scene(3);
  InitReport report;
  const GaussianMixture m = initialize_on_grid(scene.volume, scene.frame, 0.1, 60, &report);
  EXPECT_LE(m.size(), 60u);
  EXPECT_GE(m.size(), 30u);  // the search lands close to the budget
  EXPECT_GT(report.foreground, 0);
  for (const auto& g : m) {
    // Centres lie where the volume is bright.
    const Eigen::Vector3d ijk = scene.frame.index_from_world(Eigen::Vector3d(g.mean[0], g.mean[1], g.mean[2]));
    const int x = static_cast<int>(std::lround(ijk.x())), y = static_cast<int>(std::lround(ijk.y())),
              z = static_cast<int>(std::lround(ijk.z()));
    EXPECT_GT(scene.volume.at(x, y, z), 0.02f);
  }
  io::Volume empty = scene.volume;
  std::fill(empty.voxels.begin(), empty.voxels.end(), 0.0f);
  EXPECT_THROW((void)initialize_on_grid(empty, scene.frame, 0.1, 60), io::InputError);
}

TEST(GmfRasterize, MatchesDirectEvaluation) {
  const Scene scene = make_scene(5);
  const std::vector<float> f = rasterize_mixture(scene.truth, scene.frame, {.cutoff = 1e9});
  for (const auto& [x, y, z] : std::vector<std::array<int, 3>>{{10, 10, 10}, {24, 30, 12}, {40, 5, 3}}) {
    const double direct = evaluate_mixture(scene.truth, scene.frame.world_from_index(Eigen::Vector3d(x, y, z)));
    EXPECT_NEAR(f[scene.volume.index(x, y, z)], direct, 1e-6);
  }
  EXPECT_GT(psnr(f, scene.volume.voxels), 100.0);  // identical up to float rounding
}

}  // namespace
}  // namespace hisnegs::gmf
