// SPDX-License-Identifier: Apache-2.0
// fit_mixture: per round, the round's model (β), its trust region and index, one
// optimizer (the brick sweep, a global Ceres problem, L-BFGS or Adam) under the time
// budget, pruning, the round's loss and foreground PSNR, density control; the
// final all-voxel 3D PSNR after the fit.
#include "gmf/fit.hpp"

#include <ceres/ceres.h>
#include <ceres/manifold.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "gmf/adam.hpp"
#include "gmf/block_index.hpp"
#include "gmf/brick_solver.hpp"
#include "gmf/density.hpp"
#include "gmf/density_ops.hpp"
#include "gmf/detail/block_cost.hpp"
#include "gmf/gaussian_math.hpp"
#include "gmf/init.hpp"
#include "gmf/objective.hpp"
#include "gmf/psnr.hpp"
#include "gmf/rasterize.hpp"
#include "gmf/samples.hpp"
#include "io/error.hpp"
#include "io/hash.hpp"
#include "io/timer.hpp"

namespace hisnegs::gmf {
namespace {

using Params = std::array<double, kGaussianParamCount>;

// The stored float parameters in double and back (same GaussianParam order).
Params to_double(const GaussianParams& g) {
  const auto a = to_array(g);
  Params p{};
  std::copy(a.begin(), a.end(), p.begin());
  return p;
}

GaussianParams to_float(const Params& p) {
  std::array<float, kGaussianParamCount> a{};
  std::transform(p.begin(), p.end(), a.begin(), [](double v) { return static_cast<float>(v); });
  return from_array(a);
}

// Wall clock of the fit: every round, its measurement and density control count
// against gmf.time_budget_s.
struct FitClock {
  io::Stopwatch watch;
  [[nodiscard]] double now() const { return watch.elapsed(); }
};

// Shared by the solvers: where log lines go and when to stop early.
struct FitLog {
  FitResult& result;
  const FitClock& clock;
  const std::function<void(const FitIteration&)>& sink;
  double stop_loss = 0;  // GmfOptions::stop_loss
  bool reached_stop_loss = false;
  // Records one line; true when the fit should stop (the loss reached stop_loss).
  bool add(const FitIteration& it) {
    result.log.push_back(it);
    if (sink) sink(it);
    if (stop_loss > 0 && it.loss <= stop_loss) reached_stop_loss = true;
    return reached_stop_loss;
  }
};

// Logs every solver iteration (cost is Ceres' ½ Σ r² over the residual blocks;
// samples no Gaussian reaches add a constant).
class LogCallback final : public ceres::IterationCallback {
 public:
  LogCallback(FitLog& log, int round, int iteration0, double constant, int K, double beta)
      : log_(log), round_(round), iteration0_(iteration0), constant_(constant), k_(K), beta_(beta) {}
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& s) override {
    FitIteration it;
    it.round = round_;
    it.iteration = iteration0_ + s.iteration;
    it.seconds = log_.clock.now();
    it.loss = s.cost + constant_;
    it.gaussians = k_;
    it.beta = beta_;
    return log_.add(it) ? ceres::SOLVER_TERMINATE_SUCCESSFULLY : ceres::SOLVER_CONTINUE;
  }

 private:
  FitLog& log_;
  int round_, iteration0_;
  double constant_;
  int k_;
  double beta_;
};

// The β a log line records: the round's softmax β, 0 for a sum.
double log_beta(const MixtureModel& model) { return model.aggregation == Aggregation::kSoftmax ? model.beta : 0.0; }

struct RoundOutcome {
  int iterations = 0;
  double final_loss = 0;
  bool converged = false;
  std::string message;
};

// One round of a trust-region solver (LM with sparse normal Cholesky or CGNR, Dogleg).
RoundOutcome solve_least_squares(const SampleSet& samples, const BlockIndex& index, std::vector<Params>& params,
                                 const std::vector<double>& lower, const std::vector<double>& upper,
                                 ceres::Manifold& manifold, const GmfOptions& options, const MixtureModel& model,
                                 int max_iterations, double seconds_left, FitLog& log, int round, int iteration0,
                                 int K) {
  ceres::Problem::Options po;
  po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  for (std::size_t k = 0; k < params.size(); ++k) {
    const std::size_t at = kGaussianParamCount * k;
    detail::add_gaussian_block(problem, params[k].data(), &manifold, &lower[at], &upper[at]);
  }
  const double constant = unreached_loss(samples, index);
  for (std::size_t b = 0; b < samples.blocks(); ++b) {
    const auto ids = index.of(b);
    if (ids.empty()) continue;
    std::vector<double*> blocks;
    blocks.reserve(ids.size());
    for (std::uint32_t k : ids) blocks.push_back(params[k].data());
    problem.AddResidualBlock(new detail::BlockCost(samples, b, ids.size(), model), nullptr, blocks);
  }
  ceres::Solver::Options so;
  so.max_num_iterations = max_iterations;
  so.max_solver_time_in_seconds = seconds_left;
  so.num_threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  so.minimizer_progress_to_stdout = false;
  so.logging_type = ceres::SILENT;
  so.trust_region_strategy_type = options.optimizer == Optimizer::kDogleg ? ceres::DOGLEG : ceres::LEVENBERG_MARQUARDT;
  so.linear_solver_type =
      options.optimizer == Optimizer::kLevenbergMarquardtCgnr ? ceres::CGNR : ceres::SPARSE_NORMAL_CHOLESKY;
  LogCallback callback(log, round, iteration0, constant, K, log_beta(model));
  so.callbacks.push_back(&callback);
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  if (summary.termination_type == ceres::FAILURE) {
    // e.g. a non-finite residual or Jacobian at the start; Ceres rejects non-finite steps itself
    throw std::runtime_error("fit failed in round " + std::to_string(round) + ": " + summary.message);
  }
  RoundOutcome out;
  out.iterations = summary.iterations.empty() ? 0 : summary.iterations.back().iteration;
  out.final_loss = summary.final_cost + constant;
  out.converged = summary.termination_type == ceres::CONVERGENCE;
  out.message = summary.message;
  return out;
}

class ObjectiveFunction final : public ceres::FirstOrderFunction {
 public:
  explicit ObjectiveFunction(const FitObjective& objective) : objective_(objective) {}
  bool Evaluate(const double* parameters, double* cost, double* gradient) const override {
    *cost = objective_.evaluate(parameters, gradient);
    return std::isfinite(*cost);
  }
  int NumParameters() const override { return static_cast<int>(objective_.parameters()); }

 private:
  const FitObjective& objective_;
};

// One round of L-BFGS (ceres::GradientProblem). Ceres' line-search solver has no
// bounds, so the result is clamped to the round's box afterwards (the quaternion
// needs none: the loss normalizes it and its gradient is tangent).
RoundOutcome solve_lbfgs(const FitObjective& objective, double* x, const std::vector<double>& lower,
                         const std::vector<double>& upper, int max_iterations, double seconds_left, FitLog& log,
                         int round, int iteration0, int K, double beta) {
  ceres::GradientProblem problem(new ObjectiveFunction(objective));
  ceres::GradientProblemSolver::Options go;
  go.line_search_direction_type = ceres::LBFGS;
  go.max_num_iterations = max_iterations;
  go.max_solver_time_in_seconds = seconds_left;
  go.logging_type = ceres::SILENT;
  LogCallback callback(log, round, iteration0, 0.0, K, beta);
  go.callbacks.push_back(&callback);
  ceres::GradientProblemSolver::Summary summary;
  ceres::Solve(go, problem, x, &summary);
  for (std::size_t i = 0; i < lower.size(); ++i) x[i] = std::clamp(x[i], lower[i], upper[i]);
  RoundOutcome out;
  out.iterations = summary.iterations.empty() ? 0 : summary.iterations.back().iteration;
  out.final_loss = objective.evaluate(x, nullptr);
  out.converged = summary.termination_type == ceres::CONVERGENCE;
  out.message = summary.message;
  return out;
}

// One round of Adam (the report's PyTorch baseline, gmf/adam.hpp): β1 0.9, β2 0.999,
// ε 1e-8, step gmf.adam_learning_rate, times the smallest voxel size for means
// (world units); each step is projected onto the round's box. The moments carry over
// from the previous round when K did not change (a restart spikes the loss). A step
// is not started when it would end past the time left. `report` (null: `objective`)
// is what the logged loss is measured with, when that is another β.
RoundOutcome solve_adam(const FitObjective& objective, const FitObjective* report, double* x,
                        const std::vector<double>& lower, const std::vector<double>& upper, const GmfOptions& options,
                        Adam<double>& adam, int max_iterations, double seconds_left, double min_voxel, FitLog& log,
                        int round, int iteration0, int K, double beta) {
  const std::size_t n = objective.parameters();
  if (adam.gaussians() != n / kGaussianParamCount) adam = Adam<double>(AdamOptions{}, n / kGaussianParamCount);
  std::vector<double> g(n);
  const double lr = options.adam_learning_rate;
  const GroupRates rates = {lr * min_voxel, lr, lr, lr};
  const std::span<double> params(x, n);
  io::Stopwatch round_watch;
  RoundOutcome out;
  double loss = 0, step_seconds = 0;
  int step = 0;
  for (; step < max_iterations && round_watch.elapsed() + step_seconds < seconds_left; ++step) {
    const double t0 = round_watch.elapsed();
    loss = objective.evaluate(x, g.data());
    if (!std::isfinite(loss)) {
      throw std::runtime_error("fit diverged in round " + std::to_string(round) + ", Adam step " +
                               std::to_string(step + 1) + ": the loss is not finite");
    }
    if (const std::string bad = describe_non_finite<double>(g, "gradient"); !bad.empty()) {
      throw std::runtime_error("fit diverged in round " + std::to_string(round) + ", Adam step " +
                               std::to_string(step + 1) + ": " + bad + " is not finite");
    }
    FitIteration it;
    it.round = round;
    it.iteration = iteration0 + step;
    it.seconds = log.clock.now();
    it.loss = report != nullptr ? report->evaluate(x, nullptr) : loss;
    it.gaussians = K;
    it.beta = beta;
    if (log.add(it)) break;  // at stop_loss: x is the point that reached it
    adam.step(params, g, rates);
    for (std::size_t i = 0; i < n; ++i) x[i] = std::clamp(x[i], lower[i], upper[i]);
    (void)bound_axis_ratio(std::span<double>(x, n), options.max_axis_ratio);
    step_seconds = round_watch.elapsed() - t0;
  }
  out.iterations = step;
  out.final_loss = loss;
  out.message = "Adam: " + std::to_string(step) + " steps";
  return out;
}

}  // namespace

namespace {

// One round's problem: the parameters in double, the block index padded to the
// round's trust region, and the box bounds of every parameter.
struct RoundProblem {
  std::vector<Params> params;
  BlockIndex index;
  std::vector<double> lower, upper;
  [[nodiscard]] double* x() { return params.empty() ? nullptr : params[0].data(); }
};
static_assert(sizeof(Params) == kGaussianParamCount * sizeof(double), "Params must be a plain array of doubles");

// Per-round trust region on each Gaussian's geometry: its mean stays within one
// (largest) voxel of the round's start and its scales grow by at most kScaleGrowth,
// and the index is padded to match (and by jitter_reach for moved samples), so a
// Gaussian cannot reach samples outside its residual blocks during the round. Without it, Gaussians drifted into
// unwatched space and the next round's loss jumped by four orders of magnitude on op1. Scales stay within [0.2 smallest
// voxel, 32 largest voxel]; everything else is free.
RoundProblem prepare_round(const GaussianMixture& mixture, const SampleSet& samples, const io::WorldFrame& frame,
                           const GmfOptions& options) {
  constexpr double kScaleGrowth = 1.25;
  const double min_voxel = frame.voxel_size().minCoeff(), max_voxel = frame.voxel_size().maxCoeff();
  const double move = max_voxel;
  RoundProblem r;
  r.params.resize(mixture.size());
  for (std::size_t k = 0; k < mixture.size(); ++k) r.params[k] = to_double(mixture[k]);
  r.index = build_block_index(mixture, samples, frame, options.mahalanobis_cutoff, kScaleGrowth,
                              Eigen::Vector3d::Constant(move) + jitter_reach(frame, options.jitter()));
  const std::size_t n = r.params.size() * kGaussianParamCount;
  r.lower.assign(n, -std::numeric_limits<double>::infinity());
  r.upper.assign(n, std::numeric_limits<double>::infinity());
  const double largest = options.max_scale_world > 0 ? options.max_scale_world : std::min(0.5, 32.0 * max_voxel);
  const double scale_lo = std::log(0.2 * min_voxel), scale_hi = std::log(std::max(0.2 * min_voxel, largest));
  for (std::size_t k = 0; k < r.params.size(); ++k) {
    Params& p = r.params[k];
    double* lo = r.lower.data() + kGaussianParamCount * k;
    double* hi = r.upper.data() + kGaussianParamCount * k;
    for (int i = 0; i < 3; ++i) {
      p[kLogScale0 + i] = std::clamp(p[kLogScale0 + i], scale_lo, scale_hi);
      lo[kLogScale0 + i] = scale_lo;
      hi[kLogScale0 + i] = std::max(scale_lo, std::min(scale_hi, p[kLogScale0 + i] + std::log(kScaleGrowth)));
      lo[kMeanX + i] = p[kMeanX + i] - move;
      hi[kMeanX + i] = p[kMeanX + i] + move;
    }
    if (k < options.frozen) {  // held fixed: a box of one point (Adam projects onto it)
      std::copy(p.begin(), p.end(), lo);
      std::copy(p.begin(), p.end(), hi);
    }
  }
  return r;
}

// What the optimizers keep between rounds.
struct SolverState {
  Adam<double> adam;  // the moments, kept while K does not change
};

// The brick sweep as one round: the partition of this round's Gaussians and one
// sweep in which each brick gets gmf.brick_iterations LM iterations.
RoundOutcome solve_bricks(RoundProblem& r, const SampleSet& samples, const io::WorldFrame& frame,
                          const GmfOptions& options, const MixtureModel& model, const MixtureModel& report,
                          double seconds_left, FitLog& log, int round, int iteration0) {
  io::Stopwatch watch;
  {  // the round's starting loss, as the other solvers log it (their iteration 0)
    const FitObjective objective(samples, r.index, r.params.size(), report);
    FitIteration it;
    it.round = round;
    it.iteration = iteration0;
    it.seconds = log.clock.now();
    it.loss = objective.evaluate(r.x(), nullptr);
    it.gaussians = static_cast<int>(r.params.size());
    it.beta = log_beta(report);
    if (log.add(it)) return RoundOutcome{.message = "reached gmf.stop_loss"};
  }
  const BrickPartition partition =
      partition_into_bricks(r.params, r.index, frame, options.brick_voxels, options.brick_gaussians);
  BrickSweepOptions so;
  so.model = model;
  so.iterations = options.brick_iterations;
  so.seconds_left = seconds_left - watch.elapsed();
  const BrickSweepStats stats = sweep_bricks(samples, r.index, partition, r.params, r.lower, r.upper, so);
  RoundOutcome out;
  out.iterations = static_cast<int>(std::min<std::int64_t>(stats.iterations, 1 << 30));
  out.message = "brick LM: " + std::to_string(partition.gaussians.size()) + " bricks in " +
                std::to_string(partition.colours.size()) + " colours" +
                (stats.bricks_skipped > 0 ? ", " + std::to_string(stats.bricks_skipped) + " left for time" : "");
  return out;
}

// The configured optimizer on one round's problem.
// Adam and the brick LM log the loss under `report` (GmfOptions::report_model); the
// others solve at it (GmfOptions::validate).
RoundOutcome solve_round(RoundProblem& r, const SampleSet& samples, const io::WorldFrame& frame,
                         const GmfOptions& options, const MixtureModel& model, const MixtureModel& report,
                         SolverState& state, ceres::Manifold& manifold, int max_iterations, double seconds_left,
                         FitLog& log, int round, int iteration0) {
  const int K = static_cast<int>(r.params.size());
  const double min_voxel = frame.voxel_size().minCoeff();
  switch (options.optimizer) {
    case Optimizer::kBrickLm:
      return solve_bricks(r, samples, frame, options, model, report, seconds_left, log, round, iteration0);
    case Optimizer::kLbfgs: {
      const FitObjective objective(samples, r.index, r.params.size(), model);
      return solve_lbfgs(objective, r.x(), r.lower, r.upper, max_iterations, seconds_left, log, round, iteration0, K,
                         log_beta(model));
    }
    case Optimizer::kAdam: {
      const FitObjective objective(samples, r.index, r.params.size(), model);
      std::optional<FitObjective> at_report;
      if (report.beta != model.beta) at_report.emplace(samples, r.index, r.params.size(), report);
      return solve_adam(objective, at_report ? &*at_report : nullptr, r.x(), r.lower, r.upper, options, state.adam,
                        max_iterations, seconds_left, min_voxel, log, round, iteration0, K, log_beta(report));
    }
    default:
      return solve_least_squares(samples, r.index, r.params, r.lower, r.upper, manifold, options, model, max_iterations,
                                 seconds_left, log, round, iteration0, K);
  }
}

// Back to float, pruning a < prune_intensity; returns how many were pruned.
int take_round_result(RoundProblem& r, const GmfOptions& options, GaussianMixture& mixture) {
  // Every optimizer's result within the axis ratio (Adam keeps it at each step).
  (void)bound_axis_ratio(std::span<double>(r.x(), r.params.size() * kGaussianParamCount), options.max_axis_ratio);
  for (std::size_t k = 0; k < r.params.size(); ++k) mixture[k] = to_float(r.params[k]);
  const std::vector<std::uint32_t> kept = bright_gaussians(flat_params(mixture), options.prune_intensity);
  const int pruned = static_cast<int>(mixture.size() - kept.size());
  keep_gaussians(mixture, kept);
  return pruned;
}

// The loss and the foreground PSNR of `mixture` under `model` (one evaluation of
// every sample block of `index`, the mixture's own block index).
struct SampleFit {
  double loss = 0;
  double psnr_fg = 0;
};
SampleFit measure_on_samples(const GaussianMixture& mixture, const SampleSet& samples, const BlockIndex& index,
                             const MixtureModel& model) {
  const FitObjective objective(samples, index, mixture.size(), model);
  std::vector<double> x(mixture.size() * kGaussianParamCount);
  const auto flat = flat_params(mixture);
  std::copy(flat.begin(), flat.end(), x.begin());
  double fg = 0;
  SampleFit out;
  out.loss = objective.evaluate(x.data(), nullptr, &fg);
  out.psnr_fg = samples.foreground > 0 ? psnr_from_mse(fg / static_cast<double>(samples.foreground)) : 0.0;
  return out;
}

}  // namespace

SampleSet fit_samples(const io::SparseGrid& grid, const GmfOptions& options) {
  options.validate();
  return extract_samples(grid, options.background_weight, options.residual_block_voxels, options.outside_voxels);
}

FitResult fit_mixture(const io::Volume& volume, const io::SparseGrid& grid, GaussianMixture& mixture,
                      const GmfOptions& options, const std::function<void(const FitIteration&)>& on_progress) {
  return fit_mixture(volume, fit_samples(grid, options), grid.frame(), mixture, options, on_progress);
}

FitResult fit_mixture(const io::Volume& volume, const SampleSet& centres, const io::WorldFrame& frame,
                      GaussianMixture& mixture, const GmfOptions& options,
                      const std::function<void(const FitIteration&)>& on_progress) {
  options.validate();
  FitClock clock;
  FitResult result;
  FitLog log{result, clock, on_progress, options.stop_loss};
  detail::GaussianManifold manifold;
  SolverState state;
  int iterations = 0;
  MixtureModel model = options.model(0);
  MixtureModel report = options.report_model(0);  // what the log measures
  // The round's measurement and density control must fit after its solve: the
  // solve gets the time left minus what they took last round.
  double overhead = 0;
  const double jitter = options.jitter();  // 0: every round samples the voxel centres
  for (int round = 0; round < options.rounds; ++round) {
    const double left = options.time_budget_s - clock.now() - overhead;
    if (left <= 0) {
      result.stop_reason = "time budget";
      break;
    }
    model = options.model(round);
    report = options.report_model(round);
    int round_iterations = options.iterations_per_round;
    if (options.max_iterations > 0) round_iterations = std::min(round_iterations, options.max_iterations - iterations);
    // This round's samples: the voxel centres, or each moved within its voxel.
    const SampleSet moved = jitter > 0
                                ? jitter_samples(centres, volume, frame, jitter,
                                                 io::splitmix64(options.seed) + static_cast<std::uint64_t>(round))
                                : SampleSet{};
    const SampleSet& samples = jitter > 0 ? moved : centres;
    RoundProblem problem = prepare_round(mixture, samples, frame, options);
    const RoundOutcome outcome = solve_round(problem, samples, frame, options, model, report, state, manifold,
                                             round_iterations, left, log, round, iterations);
    const double solved_at = clock.now();
    iterations += outcome.iterations;
    result.stop_reason = outcome.message;
    FitRound stats;
    stats.round = round;
    stats.pruned = take_round_result(problem, options, mixture);
    problem = RoundProblem{};  // its padded index is the largest allocation: gone before the next index is built
    result.pruned += stats.pruned;
    // The round's result's block index: for its measurement and its density control.
    const BlockIndex current =
        build_block_index(mixture, samples, frame, model.cutoff, 1.0, jitter_reach(frame, jitter));
    const SampleFit fit = measure_on_samples(mixture, samples, current, report);
    FitIteration end;
    end.round = round;
    end.iteration = iterations;
    end.seconds = clock.now();
    end.loss = fit.loss;
    end.psnr_fg = fit.psnr_fg;
    end.gaussians = static_cast<int>(mixture.size());
    end.beta = log_beta(report);
    log.add(end);
    result.final_psnr_fg = fit.psnr_fg;
    const bool last = log.reached_stop_loss || (options.max_iterations > 0 && iterations >= options.max_iterations);
    if (log.reached_stop_loss) {
      result.stop_reason = "reached gmf.stop_loss";
    } else if (last) {
      result.stop_reason = "gmf.max_iterations";
    }
    // Density control for the next round (not after the last one, nor when out of time).
    if (!last && options.densify && round + 1 < options.rounds && clock.now() < options.time_budget_s) {
      const DensityChange change = adapt_density(mixture, samples, current, frame, options, model);
      stats.split = change.split;
      stats.cloned = change.cloned;
    }
    overhead = clock.now() - solved_at;
    if (!last) stats.gaussians = static_cast<int>(mixture.size());
    result.rounds.push_back(stats);
    if (last) break;
    if (outcome.converged && round > 0 && stats.split == 0 && stats.cloned == 0 &&
        options.model(round + 1).beta == model.beta) {
      result.stop_reason = "converged: " + outcome.message;
      break;
    }
  }
  result.seconds = clock.now();
  result.final_beta = log_beta(report);
  io::Stopwatch measuring;
  result.final_psnr_3d = mixture_psnr(mixture, frame, RasterizeOptions::of(report), volume.voxels);
  if (jitter > 0 && !result.log.empty()) {
    // The rounds measured their moved samples; the result is measured, like the
    // 3D PSNR, at the voxel centres.
    const BlockIndex index = build_block_index(mixture, centres, frame, report.cutoff);
    result.final_psnr_fg = measure_on_samples(mixture, centres, index, report).psnr_fg;
  }
  result.measuring_seconds = measuring.elapsed();
  FitIteration final_line = result.log.empty() ? FitIteration{} : result.log.back();
  final_line.psnr_3d = result.final_psnr_3d;
  if (jitter > 0 && final_line.psnr_fg >= 0) final_line.psnr_fg = result.final_psnr_fg;
  final_line.gaussians = static_cast<int>(mixture.size());
  log.add(final_line);
  return result;
}

}  // namespace hisnegs::gmf
