// SPDX-License-Identifier: Apache-2.0
// Optimizer comparison, done honestly: every optimizer from
// the same initial mixture, samples, loss and time budget, with density control
// off so K is the same for all; the target is the loss Adam reaches after N steps.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "gmf/fit.hpp"
#include "gmf/round_solver.hpp"

namespace hisnegs::gmf {

struct CompareOptions {
  // Optimizers in the order they run; Adam (when present) always runs first, since
  // its loss after adam_steps is every other run's target. The global exact solvers
  // (lm, dogleg) run only when asked: their normal equations fill in beyond memory
  // on real stacks.
  std::vector<Optimizer> optimizers = {Optimizer::kAdam, Optimizer::kBrickLm, Optimizer::kLevenbergMarquardtCgnr,
                                       Optimizer::kLbfgs};
  double time_budget_s = 300;   // wall-clock budget of each run (the final 3D PSNR excluded), > 0
  int adam_steps = 2000;        // Adam's steps that define the target loss, >= 1
  bool stop_at_target = false;  // end a run once it reaches the target (saves time; its curve stops there)
  // The optimizers (Adam, brick-lm) that follow the fit's β schedule (gmf.beta_start
  // → beta_end, as `fit` does); every other one solves at beta_end from the start.
  // Every run's loss is logged at beta_end, so all are measured on one objective.
  // Default: the brick LM only, each optimizer at its best on op1. From the grid
  // init the brick LM's Gauss–Newton model is useless at β 64 (with continuation it
  // reaches a loss of 142 in 98 s, without 508), while Adam ends higher with it
  // (docs/benchmarks.md).
  std::vector<Optimizer> continuation = {Optimizer::kBrickLm};
  // Registered (gmf/optimizers.def) or user-given optimizers (Python callables), run
  // after the built-in ones in this order, each at gmf.beta_end from the start.
  std::vector<NamedSolver> custom;

  void validate() const;  // throws InputError("compare.FIELD = VALUE: rule")
};

struct OptimizerRun {
  Optimizer optimizer{};
  std::string name;  // as in the config: lm, lm-cgnr, dogleg, lbfgs, adam; a custom solver's own name
  FitResult result;
  double seconds_to_target = -1;  // first logged time with loss <= target; < 0 when never reached
  double final_loss = 0;
  int iterations = 0;
  int gaussians = 0;          // K at the end (only pruning changes it)
  std::string failure;        // non-empty when the run failed (e.g. "out of memory"); the log is kept
  bool continuation = false;  // followed the β schedule (CompareOptions::continuation)
};

struct Comparison {
  double target_loss = -1;  // Adam's loss after its steps; < 0 without an Adam run
  int adam_steps_done = 0;  // fewer than CompareOptions::adam_steps when Adam ran out of time
  std::vector<OptimizerRun> runs;
};

// The configured name of an optimizer ("lm-cgnr", ...).
std::string optimizer_name(Optimizer optimizer);
// The built-in optimizer of that configured name, if one is.
std::optional<Optimizer> find_builtin_optimizer(std::string_view name);
// The built-in optimizers called `names`; io::InputError naming `option` for another name.
std::vector<Optimizer> builtin_optimizers(const std::vector<std::string>& names, std::string_view option);
// Adds the optimizers called `names` to `options`, in order: the built-in ones to
// `optimizers`, the registered ones (gmf/optimizers.def) to `custom`;
// io::InputError naming `option` (and the registered names) for another name.
void add_optimizers(CompareOptions& options, const std::vector<std::string>& names, std::string_view option);

// Runs the comparison on `samples` (fit_samples()) of `volume` in `frame`. `base`
// supplies everything but the optimizer, the budget and density control; `initial`
// is copied for every run. `on_progress(run, line)` is called for every log line,
// `after_run(comparison so far)` after each optimizer (to save partial results). A
// run that fails (out of memory, a solver error) is recorded as failed and the
// others still run; bad input (io::InputError) and io::Interrupted are rethrown.
Comparison compare_optimizers(const io::Volume& volume, const SampleSet& samples, const io::WorldFrame& frame,
                              const GaussianMixture& initial, const GmfOptions& base, const CompareOptions& options,
                              const std::function<void(const OptimizerRun&, const FitIteration&)>& on_progress = {},
                              const std::function<void(const Comparison&)>& after_run = {});

}  // namespace hisnegs::gmf
