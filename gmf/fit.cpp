// fit_mixture: Ceres problem assembly per round (parameter blocks per Gaussian,
// one BrickCost per sample brick), solve under the time budget, prune, measure.
#include "gmf/fit.hpp"

#include <ceres/ceres.h>
#include <ceres/manifold.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <thread>

#include "gmf/brick_index.hpp"
#include "gmf/detail/brick_cost.hpp"
#include "gmf/gaussian_math.hpp"
#include "gmf/init.hpp"
#include "gmf/samples.hpp"
#include "io/error.hpp"
#include "io/timer.hpp"

namespace hisnegs::gmf {
namespace {

using Params = std::array<double, kNumGaussianParams>;

Params to_double(const GaussianParams& g) {
  Params p{};
  for (int i = 0; i < 3; ++i) p[kMeanX + i] = g.mean[i];
  for (int i = 0; i < 3; ++i) p[kLogScale0 + i] = g.log_scale[i];
  for (int i = 0; i < 4; ++i) p[kRotW + i] = g.rotation[i];
  p[kLogit] = g.intensity_logit;
  return p;
}

GaussianParams to_float(const Params& p) {
  GaussianParams g;
  for (int i = 0; i < 3; ++i) g.mean[i] = static_cast<float>(p[kMeanX + i]);
  for (int i = 0; i < 3; ++i) g.log_scale[i] = static_cast<float>(p[kLogScale0 + i]);
  for (int i = 0; i < 4; ++i) g.rotation[i] = static_cast<float>(p[kRotW + i]);
  g.intensity_logit = static_cast<float>(p[kLogit]);
  return g;
}

// Logs every solver iteration (cost is Ceres' ½ Σ r² over the residual blocks;
// samples no Gaussian reaches add a constant).
class LogCallback final : public ceres::IterationCallback {
 public:
  LogCallback(FitResult& result, const io::Stopwatch& watch, int round, int iteration0, double constant, int K,
              const std::function<void(const FitIteration&)>& sink)
      : result_(result), watch_(watch), round_(round), iteration0_(iteration0), constant_(constant), k_(K), sink_(sink) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
    FitIteration it;
    it.round = round_;
    it.iteration = iteration0_ + s.iteration;
    it.seconds = watch_.elapsed();
    it.loss = s.cost + constant_;
    it.gaussians = k_;
    result_.log.push_back(it);
    if (sink_) sink_(it);
    return ceres::SOLVER_CONTINUE;
  }

 private:
  FitResult& result_;
  const io::Stopwatch& watch_;
  int round_, iteration0_;
  double constant_;
  int k_;
  const std::function<void(const FitIteration&)>& sink_;
};

}  // namespace

FitResult fit_mixture(const io::Volume& volume, const io::SparseGrid& grid, GaussianMixture& mixture,
                      const GmfOptions& options, const std::function<void(const FitIteration&)>& on_progress) {
  options.validate();
  if (options.optimizer == Optimizer::kLbfgs || options.optimizer == Optimizer::kAdam) {
    throw io::InputError("gmf.optimizer: lbfgs and adam are not implemented yet; use lm, lm-cgnr or dogleg");
  }
  io::Stopwatch watch;
  FitResult result;
  const io::WorldFrame frame = grid.frame();
  const SampleSet samples = extract_samples(grid, options.background_weight, options.residual_block_voxels);
  const double min_voxel = frame.voxel_size().minCoeff();
  const double max_voxel = frame.voxel_size().maxCoeff();
  ceres::QuaternionManifold quaternion_manifold;
  int iterations = 0;
  for (int round = 0; round < options.rounds; ++round) {
    const double left = options.time_budget_s - watch.elapsed();
    if (left <= 0) {
      result.stop_reason = "time budget";
      break;
    }
    std::vector<Params> params(mixture.size());
    for (std::size_t k = 0; k < mixture.size(); ++k) params[k] = to_double(mixture[k]);
    // Per-round trust region on each Gaussian's geometry (bounds below): its mean
    // stays within one (largest) voxel of the round's start and its scales grow by
    // at most kScaleGrowth, and the index is padded to match, so a Gaussian cannot
    // reach samples outside its residual blocks during the round. Without it,
    // Gaussians drifted into unwatched space and the next round's loss jumped
    // from 3 to 3e4 on op1.
    constexpr double kScaleGrowth = 1.25;
    const double move = max_voxel;
    const BrickIndex index = build_brick_index(mixture, samples, frame, options.mahalanobis_cutoff, kScaleGrowth, move);

    ceres::Problem::Options po;
    po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
    ceres::Problem problem(po);
    for (auto& p : params) {
      problem.AddParameterBlock(&p[kMeanX], 3);
      problem.AddParameterBlock(&p[kLogScale0], 3);
      problem.AddParameterBlock(&p[kRotW], 4, &quaternion_manifold);
      problem.AddParameterBlock(&p[kLogit], 1);
      // Scales between a fifth of the smallest voxel and 32 of the largest (at most
      // half the box): keeps LM from collapsing or exploding a Gaussian.
      for (int i = 0; i < 3; ++i) {
        const double lower = std::log(0.2 * min_voxel), upper = std::log(std::min(0.5, 32.0 * max_voxel));
        p[kLogScale0 + i] = std::clamp(p[kLogScale0 + i], lower, upper);
        problem.SetParameterLowerBound(&p[kLogScale0], i, lower);
        problem.SetParameterUpperBound(&p[kLogScale0], i, std::max(lower, std::min(upper, p[kLogScale0 + i] + std::log(kScaleGrowth))));
        problem.SetParameterLowerBound(&p[kMeanX], i, p[kMeanX + i] - move);
        problem.SetParameterUpperBound(&p[kMeanX], i, p[kMeanX + i] + move);
      }
    }
    double constant = 0;  // ½ Σ (w V)² of samples no Gaussian reaches
    for (std::size_t b = 0; b < samples.bricks(); ++b) {
      const auto ids = index.of(b);
      if (ids.empty()) {
        for (std::uint32_t s = samples.brick_begin[b]; s < samples.brick_begin[b + 1]; ++s) {
          constant += 0.5 * std::pow(samples.weight[s] * samples.value[s], 2);
        }
        continue;
      }
      std::vector<double*> blocks;
      blocks.reserve(ids.size() * detail::kBlocksPerGaussian);
      for (std::uint32_t k : ids) {
        blocks.push_back(&params[k][kMeanX]);
        blocks.push_back(&params[k][kLogScale0]);
        blocks.push_back(&params[k][kRotW]);
        blocks.push_back(&params[k][kLogit]);
      }
      problem.AddResidualBlock(new detail::BrickCost(samples, b, ids, options.mahalanobis_cutoff), nullptr, blocks);
    }

    ceres::Solver::Options so;
    so.max_num_iterations = options.iterations_per_round;
    so.max_solver_time_in_seconds = left;
    so.num_threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
    so.minimizer_progress_to_stdout = false;
    so.logging_type = ceres::SILENT;
    switch (options.optimizer) {
      case Optimizer::kLevenbergMarquardt:
        so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
        so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
        break;
      case Optimizer::kLevenbergMarquardtCgnr:
        so.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
        so.linear_solver_type = ceres::CGNR;
        break;
      case Optimizer::kDogleg:
        so.trust_region_strategy_type = ceres::DOGLEG;
        so.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
        break;
      default:
        break;
    }
    LogCallback callback(result, watch, round, iterations, constant, static_cast<int>(mixture.size()), on_progress);
    so.callbacks.push_back(&callback);
    so.update_state_every_iteration = false;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    iterations += summary.iterations.empty() ? 0 : summary.iterations.back().iteration;
    result.stop_reason = summary.message;

    // Back to float, pruning a < prune_intensity.
    GaussianMixture next;
    next.reserve(params.size());
    for (const Params& p : params) {
      const double a = 1.0 / (1.0 + std::exp(-p[kLogit]));
      if (a < options.prune_intensity) {
        ++result.pruned;
        continue;
      }
      next.push_back(to_float(p));
    }
    mixture = std::move(next);

    FitIteration end;
    end.round = round;
    end.iteration = iterations;
    end.seconds = watch.elapsed();
    end.loss = summary.final_cost + constant;
    end.psnr_3d = psnr_3d(rasterize_mixture(mixture, frame, options.mahalanobis_cutoff), volume);
    end.gaussians = static_cast<int>(mixture.size());
    result.log.push_back(end);
    if (on_progress) on_progress(end);
    result.final_psnr_3d = end.psnr_3d;
    if (summary.termination_type == ceres::CONVERGENCE && round > 0) {
      result.stop_reason = "converged: " + summary.message;
      break;
    }
  }
  result.seconds = watch.elapsed();
  return result;
}

}  // namespace hisnegs::gmf
