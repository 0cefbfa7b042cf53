// SPDX-License-Identifier: Apache-2.0
// fit_mixture: the round loop (RoundLoop: per round the model (β), samples, trust
// region and index, one optimizer (the brick sweep, a global Ceres problem, L-BFGS
// or Adam) under the time budget, pruning, the round's loss and foreground PSNR,
// density control; the final all-voxel 3D PSNR after the last round).
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

#include "gmf/core/adam.hpp"
#include "gmf/block_index.hpp"
#include "gmf/brick_solver.hpp"
#include "gmf/density.hpp"
#include "gmf/core/density_ops.hpp"
#include "gmf/detail/block_cost.hpp"
#include "gmf/core/gaussian_math.hpp"
#include "gmf/init.hpp"
#include "gmf/objective.hpp"
#include "gmf/core/psnr.hpp"
#include "gmf/core/rasterize.hpp"
#include "gmf/round_solver.hpp"
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

// One round's problem: the parameters in double, the block index padded to the
// round's trust region, and the box bounds of every parameter.
struct RoundProblem {
  std::vector<Params> params;
  BlockIndex index;
  std::vector<double> lower, upper;
  [[nodiscard]] double* x() { return params.empty() ? nullptr : params[0].data(); }
  [[nodiscard]] int gaussians() const { return static_cast<int>(params.size()); }
};
static_assert(sizeof(Params) == kGaussianParamCount * sizeof(double), "Params must be a plain array of doubles");

// What a solver is given for one round besides its problem: the round's samples and
// models, where its log lines go, and how far it may go.
struct RoundContext {
  const SampleSet& samples;
  const io::WorldFrame& frame;
  const GmfOptions& options;
  const MixtureModel& model;   // what the round solves
  const MixtureModel& report;  // what its log lines measure (GmfOptions::report_model)
  FitLog& log;
  int round = 0;
  int iteration0 = 0;      // iterations of the rounds before
  int max_iterations = 0;  // this round's
  double seconds_left = 0;
};

// One round of a trust-region solver (LM with sparse normal Cholesky or CGNR, Dogleg).
RoundOutcome solve_least_squares(RoundProblem& r, const RoundContext& c, ceres::Manifold& manifold) {
  ceres::Problem::Options po;
  po.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(po);
  for (std::size_t k = 0; k < r.params.size(); ++k) {
    const std::size_t at = kGaussianParamCount * k;
    detail::add_gaussian_block(problem, r.params[k].data(), &manifold, &r.lower[at], &r.upper[at]);
  }
  const double constant = unreached_loss(c.samples, r.index);
  for (std::size_t b = 0; b < c.samples.blocks(); ++b) {
    const auto ids = r.index.of(b);
    if (ids.empty()) continue;
    std::vector<double*> blocks;
    blocks.reserve(ids.size());
    for (std::uint32_t k : ids) blocks.push_back(r.params[k].data());
    problem.AddResidualBlock(new detail::BlockCost(c.samples, b, ids.size(), c.model), nullptr, blocks);
  }
  ceres::Solver::Options so;
  so.max_num_iterations = c.max_iterations;
  so.max_solver_time_in_seconds = c.seconds_left;
  so.num_threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  so.minimizer_progress_to_stdout = false;
  so.logging_type = ceres::SILENT;
  so.trust_region_strategy_type =
      c.options.optimizer == Optimizer::kDogleg ? ceres::DOGLEG : ceres::LEVENBERG_MARQUARDT;
  so.linear_solver_type =
      c.options.optimizer == Optimizer::kLevenbergMarquardtCgnr ? ceres::CGNR : ceres::SPARSE_NORMAL_CHOLESKY;
  LogCallback callback(c.log, c.round, c.iteration0, constant, r.gaussians(), log_beta(c.model));
  so.callbacks.push_back(&callback);
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  if (summary.termination_type == ceres::FAILURE) {
    // e.g. a non-finite residual or Jacobian at the start; Ceres rejects non-finite steps itself
    throw std::runtime_error("fit failed in round " + std::to_string(c.round) + ": " + summary.message);
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
RoundOutcome solve_lbfgs(RoundProblem& r, const RoundContext& c) {
  const FitObjective objective(c.samples, r.index, r.params.size(), c.model);
  double* x = r.x();
  ceres::GradientProblem problem(new ObjectiveFunction(objective));
  ceres::GradientProblemSolver::Options go;
  go.line_search_direction_type = ceres::LBFGS;
  go.max_num_iterations = c.max_iterations;
  go.max_solver_time_in_seconds = c.seconds_left;
  go.logging_type = ceres::SILENT;
  LogCallback callback(c.log, c.round, c.iteration0, 0.0, r.gaussians(), log_beta(c.model));
  go.callbacks.push_back(&callback);
  ceres::GradientProblemSolver::Summary summary;
  ceres::Solve(go, problem, x, &summary);
  for (std::size_t i = 0; i < r.lower.size(); ++i) x[i] = std::clamp(x[i], r.lower[i], r.upper[i]);
  RoundOutcome out;
  out.iterations = summary.iterations.empty() ? 0 : summary.iterations.back().iteration;
  out.final_loss = objective.evaluate(x, nullptr);
  out.converged = summary.termination_type == ceres::CONVERGENCE;
  out.message = summary.message;
  return out;
}

// One round of Adam (the report's PyTorch baseline, gmf/core/adam.hpp): β1 0.9, β2 0.999,
// ε 1e-8, step gmf.adam_learning_rate, times the smallest voxel size for means
// (world units); each step is projected onto the round's box. The moments carry over
// from the previous round, following its pruning and density control (a restart
// spiked the loss: its first step moves every parameter by the full rate). A step
// is not started when it would end past the time left. The logged loss is measured
// at the report model's β when that differs from the solved one.
RoundOutcome solve_adam(RoundProblem& r, const RoundContext& c, Adam<double>& adam) {
  double* x = r.x();
  // The frozen Gaussians (gmf.frozen: a seam refit's neighbours) are combined once.
  const std::size_t frozen = std::min(c.options.frozen, r.params.size());
  FitObjective objective(c.samples, r.index, r.params.size(), c.model);
  objective.hold_fixed(x, frozen);
  std::optional<FitObjective> report;
  if (c.report.beta != c.model.beta) {
    report.emplace(c.samples, r.index, r.params.size(), c.report);
    report->hold_fixed(x, frozen);
  }
  const std::size_t n = objective.parameters();
  if (adam.gaussians() != n / kGaussianParamCount) adam = Adam<double>(AdamOptions{}, n / kGaussianParamCount);
  std::vector<double> g(n);
  const double lr = c.options.adam_learning_rate;
  const GroupRates rates = {lr * c.frame.voxel_size().minCoeff(), lr, lr, lr};
  const std::span<double> params(x, n);
  io::Stopwatch round_watch;
  RoundOutcome out;
  double loss = 0, step_seconds = 0;
  int step = 0;
  for (; step < c.max_iterations && round_watch.elapsed() + step_seconds < c.seconds_left; ++step) {
    const double t0 = round_watch.elapsed();
    loss = objective.evaluate(x, g.data());
    if (!std::isfinite(loss)) {
      throw std::runtime_error("fit diverged in round " + std::to_string(c.round) + ", Adam step " +
                               std::to_string(step + 1) + ": the loss is not finite");
    }
    if (const std::string bad = describe_non_finite<double>(g, "gradient"); !bad.empty()) {
      throw std::runtime_error("fit diverged in round " + std::to_string(c.round) + ", Adam step " +
                               std::to_string(step + 1) + ": " + bad + " is not finite");
    }
    FitIteration it;
    it.round = c.round;
    it.iteration = c.iteration0 + step;
    it.seconds = c.log.clock.now();
    it.loss = report ? report->evaluate(x, nullptr) : loss;
    it.gaussians = r.gaussians();
    it.beta = log_beta(c.report);
    if (c.log.add(it)) break;  // at stop_loss: x is the point that reached it
    adam.step(params, g, rates);
    for (std::size_t i = 0; i < n; ++i) x[i] = std::clamp(x[i], r.lower[i], r.upper[i]);
    (void)bound_axis_ratio(std::span<double>(x, n), c.options.max_axis_ratio);
    step_seconds = round_watch.elapsed() - t0;
  }
  out.iterations = step;
  out.final_loss = loss;
  out.message = "Adam: " + std::to_string(step) + " steps";
  return out;
}

// One round of a registered or user-given optimizer (GmfOptions::custom,
// gmf/round_solver.hpp) at the round's model. Each log() call is one log line; it
// says stop once the round's time is spent or the loss reached gmf.stop_loss. The
// result is clamped into the round's box, as L-BFGS's is.
RoundOutcome solve_custom(RoundProblem& r, const RoundContext& c) {
  const NamedSolver& solver = *c.options.custom;
  const FitObjective objective(c.samples, r.index, r.params.size(), c.model);
  const std::size_t n = objective.parameters();
  io::Stopwatch round_watch;
  int lines = 0;
  const RoundSolverProblem problem{
      .x = std::span<double>(r.x(), n),
      .lower = r.lower,
      .upper = r.upper,
      .objective = objective,
      .max_iterations = c.max_iterations,
      .seconds_left = c.seconds_left,
      .log =
          [&](double loss) {
            FitIteration it;
            it.round = c.round;
            it.iteration = c.iteration0 + lines++;
            it.seconds = c.log.clock.now();
            it.loss = loss;
            it.gaussians = r.gaussians();
            it.beta = log_beta(c.model);
            const bool reached = c.log.add(it);
            return reached || round_watch.elapsed() >= c.seconds_left;
          },
      .options = c.options,
      .frame = c.frame};
  const RoundSolverOutcome outcome = solver.solve(problem);
  double* x = r.x();
  for (std::size_t i = 0; i < n; ++i) x[i] = std::clamp(x[i], r.lower[i], r.upper[i]);
  if (const std::string bad = describe_non_finite<double>(std::span<const double>(x, n), "parameter"); !bad.empty()) {
    throw std::runtime_error(solver.name + " in round " + std::to_string(c.round) + ": " + bad + " is not finite");
  }
  RoundOutcome out;
  out.iterations = outcome.iterations;
  out.converged = outcome.converged;
  out.message = outcome.message.empty() ? solver.name : outcome.message;
  return out;
}

// The brick sweep as one round: the partition of this round's Gaussians and one
// sweep in which each brick gets gmf.brick_iterations LM iterations.
RoundOutcome solve_bricks(RoundProblem& r, const RoundContext& c) {
  io::Stopwatch watch;
  {  // the round's starting loss, as the other solvers log it (their iteration 0)
    const FitObjective objective(c.samples, r.index, r.params.size(), c.report);
    FitIteration it;
    it.round = c.round;
    it.iteration = c.iteration0;
    it.seconds = c.log.clock.now();
    it.loss = objective.evaluate(r.x(), nullptr);
    it.gaussians = r.gaussians();
    it.beta = log_beta(c.report);
    if (c.log.add(it)) return RoundOutcome{.message = "reached gmf.stop_loss"};
  }
  const BrickPartition partition =
      partition_into_bricks(r.params, r.index, c.frame, c.options.brick_voxels, c.options.brick_gaussians);
  BrickSweepOptions so;
  so.model = c.model;
  so.iterations = c.options.brick_iterations;
  so.seconds_left = c.seconds_left - watch.elapsed();
  const BrickSweepStats stats = sweep_bricks(c.samples, r.index, partition, r.params, r.lower, r.upper, so);
  RoundOutcome out;
  out.iterations = static_cast<int>(std::min<std::int64_t>(stats.iterations, 1 << 30));
  out.message = "brick LM: " + std::to_string(partition.gaussians.size()) + " bricks in " +
                std::to_string(partition.colours.size()) + " colours" +
                (stats.bricks_skipped > 0 ? ", " + std::to_string(stats.bricks_skipped) + " left for time" : "");
  return out;
}

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
  const double scale_lo = std::log(0.2 * min_voxel), scale_hi = std::log(options.largest_scale(min_voxel, max_voxel));
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

// Back to float, pruning a < prune_intensity; returns how many were pruned. Adam's
// moments, when they are this round's, follow the survivors.
int take_round_result(RoundProblem& r, const GmfOptions& options, GaussianMixture& mixture, Adam<double>& adam) {
  // Every optimizer's result within the axis ratio (Adam keeps it at each step).
  (void)bound_axis_ratio(std::span<double>(r.x(), r.params.size() * kGaussianParamCount), options.max_axis_ratio);
  for (std::size_t k = 0; k < r.params.size(); ++k) mixture[k] = to_float(r.params[k]);
  const std::vector<std::uint32_t> kept = bright_gaussians(flat_params(mixture), options.prune_intensity);
  const int pruned = static_cast<int>(mixture.size() - kept.size());
  if (pruned > 0 && adam.gaussians() == mixture.size()) adam.keep(kept);
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

// The fit's rounds, one step per method: sample (the round's samples), index (its
// trust region and padded block index), solve (the configured optimizer), log (the
// round's loss and foreground PSNR), density (pruning was in take; split and clone),
// and after the last round measure (the all-voxel 3D PSNR). The stack is reached
// only through StackAccess, so a caller that holds it by regions or on other ranks
// drives the same maths.
class RoundLoop {
 public:
  RoundLoop(const StackAccess& stack, const SampleSet& centres, const io::WorldFrame& frame, GaussianMixture& mixture,
            const GmfOptions& options, const std::function<void(const FitIteration&)>& on_progress)
      : stack_(stack),
        centres_(centres),
        frame_(frame),
        mixture_(mixture),
        options_(options),
        log_{result_, clock_, on_progress, options.stop_loss},
        jitter_(options.jitter()) {}

  FitResult run() {
    // The round's measurement and density control must fit after its solve: the
    // solve gets the time left minus what they took last round.
    double overhead = 0;
    // The final all-voxel measurement (measure()) must fit in the budget too: its
    // cost, probed on the initial mixture (1.5x: the mixture grows), is kept free.
    double final_reserve = 0;
    if (options_.time_budget_s > 0 && !mixture_.empty() && options_.measure) {
      io::Stopwatch probe;
      (void)stack_.psnr_3d(mixture_, RasterizeOptions::of(report_));
      final_reserve = 1.5 * probe.elapsed();
    }
    for (int round = 0; round < options_.rounds; ++round) {
      const double left = options_.budget_seconds() - clock_.now() - overhead - final_reserve;
      if (left <= 0) {
        result_.stop_reason = "time budget";
        break;
      }
      const bool hard = options_.hard_round(round, clock_.now());
      model_ = options_.model(round, hard);
      report_ = options_.report_model(round, hard);
      const SampleSet& samples = sample(round);
      RoundProblem problem = index(samples);
      const RoundOutcome outcome = solve(problem, samples, round, left);
      const double solved_at = clock_.now();
      iterations_ += outcome.iterations;
      result_.stop_reason = outcome.message;
      FitRound stats;
      stats.round = round;
      stats.pruned = take_round_result(problem, options_, mixture_, adam_);
      problem = RoundProblem{};  // its padded index is the largest allocation: gone before the next index is built
      result_.pruned += stats.pruned;
      // The round's result's block index: for its measurement and its density
      // control, built when one of them runs.
      std::optional<BlockIndex> current;
      const auto current_index = [&]() -> const BlockIndex& {
        if (!current) {
          current.emplace(
              build_block_index(mixture_, samples, frame_, model_.cutoff, 1.0, jitter_reach(frame_, jitter_)));
        }
        return *current;
      };
      if (options_.measure) log_round(samples, current_index(), round);
      const bool last = log_.reached_stop_loss || (options_.max_iterations > 0 && iterations_ >= options_.max_iterations);
      if (log_.reached_stop_loss) {
        result_.stop_reason = "reached gmf.stop_loss";
      } else if (last) {
        result_.stop_reason = "gmf.max_iterations";
      }
      // Density control for the next round (not after the last one, nor when out of
      // time, nor into the hard share: that refines what the softmax rounds built,
      // and its last round, cut short by the budget, could not settle new Gaussians:
      // on op3_raw the max's foreground PSNR fell from 44.6 to 40.0 dB after a split).
      if (!last && options_.densify && round + 1 < options_.rounds && clock_.now() < options_.budget_seconds() &&
          !options_.hard_round(round + 1, clock_.now())) {
        density(samples, current_index(), stats);
      }
      overhead = clock_.now() - solved_at;
      if (!last) stats.gaussians = static_cast<int>(mixture_.size());
      result_.rounds.push_back(stats);
      if (last) break;
      if (outcome.converged && round > 0 && stats.split == 0 && stats.cloned == 0 &&
          options_.model(round + 1).beta == model_.beta && hard == options_.hard_round(round + 1, clock_.now())) {
        result_.stop_reason = "converged: " + outcome.message;
        break;
      }
    }
    result_.seconds = clock_.now();
    result_.final_beta = log_beta(report_);
    moved_ = SampleSet{};  // the last round's moved samples: not needed to measure
    measure();
    return std::move(result_);
  }

 private:
  // sample: the voxel centres, or each moved within its voxel (gmf.jitter), seeded by the round.
  const SampleSet& sample(int round) {
    if (jitter_ <= 0) return centres_;
    moved_ = SampleSet{};  // the last round's are gone before this round's are made
    moved_ = stack_.jittered(centres_, jitter_, io::splitmix64(options_.seed) + static_cast<std::uint64_t>(round));
    return moved_;
  }

  // index: the round's trust region and its padded block index.
  RoundProblem index(const SampleSet& samples) const { return prepare_round(mixture_, samples, frame_, options_); }

  // solve: the configured optimizer on the round's problem. Adam and the brick LM log
  // the loss under the report model; the others solve at it (GmfOptions::validate).
  RoundOutcome solve(RoundProblem& problem, const SampleSet& samples, int round, double seconds_left) {
    int round_iterations = options_.iterations_per_round;
    if (options_.max_iterations > 0) round_iterations = std::min(round_iterations, options_.max_iterations - iterations_);
    const RoundContext c{samples, frame_, options_, model_, report_, log_, round, iterations_, round_iterations,
                         seconds_left};
    switch (options_.optimizer) {
      case Optimizer::kBrickLm:
        return solve_bricks(problem, c);
      case Optimizer::kLbfgs:
        return solve_lbfgs(problem, c);
      case Optimizer::kAdam:
        return solve_adam(problem, c, adam_);
      case Optimizer::kCustom:
        return solve_custom(problem, c);
      default:
        return solve_least_squares(problem, c, manifold_);
    }
  }

  // log: the round's loss and foreground PSNR on its samples, one line.
  void log_round(const SampleSet& samples, const BlockIndex& current, int round) {
    const SampleFit fit = measure_on_samples(mixture_, samples, current, report_);
    FitIteration end;
    end.round = round;
    end.iteration = iterations_;
    end.seconds = clock_.now();
    end.loss = fit.loss;
    end.psnr_fg = fit.psnr_fg;
    end.gaussians = static_cast<int>(mixture_.size());
    end.beta = log_beta(report_);
    log_.add(end);
    result_.final_psnr_fg = fit.psnr_fg;
  }

  // density: split and clone for the next round.
  void density(const SampleSet& samples, const BlockIndex& current, FitRound& stats) {
    const std::size_t before = mixture_.size();
    const DensityChange change = adapt_density(mixture_, samples, current, frame_, options_, model_);
    // New Gaussians (appended) start with zero moments; the others keep theirs.
    if (adam_.gaussians() == before) adam_.resize(mixture_.size());
    stats.split = change.split;
    stats.cloned = change.cloned;
  }

  // measure: the all-voxel 3D PSNR and, when the rounds measured moved samples, the
  // foreground PSNR at the voxel centres; the final log line carries both.
  void measure() {
    if (!options_.measure) return;
    io::Stopwatch measuring;
    result_.final_psnr_3d = stack_.psnr_3d(mixture_, RasterizeOptions::of(report_));
    if (jitter_ > 0 && !result_.log.empty()) {
      const BlockIndex index = build_block_index(mixture_, centres_, frame_, report_.cutoff);
      result_.final_psnr_fg = measure_on_samples(mixture_, centres_, index, report_).psnr_fg;
    }
    result_.measuring_seconds = measuring.elapsed();
    FitIteration final_line = result_.log.empty() ? FitIteration{} : result_.log.back();
    final_line.psnr_3d = result_.final_psnr_3d;
    if (jitter_ > 0 && final_line.psnr_fg >= 0) final_line.psnr_fg = result_.final_psnr_fg;
    final_line.gaussians = static_cast<int>(mixture_.size());
    log_.add(final_line);
  }

  const StackAccess& stack_;
  const SampleSet& centres_;
  const io::WorldFrame& frame_;
  GaussianMixture& mixture_;
  const GmfOptions& options_;
  FitClock clock_;
  FitResult result_;
  FitLog log_;
  const double jitter_;  // 0: every round samples the voxel centres
  SampleSet moved_;      // this round's samples when jittered
  detail::GaussianManifold manifold_;
  Adam<double> adam_;  // the moments, following pruning and density control
  int iterations_ = 0;
  MixtureModel model_ = options_.model(0);
  MixtureModel report_ = options_.report_model(0);  // what the log measures
};

}  // namespace

StackAccess stack_access(const io::Volume& volume, const io::WorldFrame& frame) {
  StackAccess s;
  s.jittered = [&volume, frame](const SampleSet& centres, double jitter, std::uint64_t seed) {
    return jitter_samples(centres, volume, frame, jitter, seed);
  };
  s.psnr_3d = [&volume, frame](const GaussianMixture& mixture, const RasterizeOptions& options) {
    return mixture_psnr(mixture, frame, options, volume.voxels);
  };
  return s;
}

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
  return fit_mixture(stack_access(volume, frame), centres, frame, mixture, options, on_progress);
}

FitResult fit_mixture(const StackAccess& stack, const SampleSet& centres, const io::WorldFrame& frame,
                      GaussianMixture& mixture, const GmfOptions& options,
                      const std::function<void(const FitIteration&)>& on_progress) {
  options.validate();
  return RoundLoop(stack, centres, frame, mixture, options, on_progress).run();
}

}  // namespace hisnegs::gmf
