// SPDX-License-Identifier: Apache-2.0
// Bring your own optimizer: the interface a stage-1 optimizer implements to run in
// the fit's round loop and in compare-optimizers beside the built-in ones, and the
// registry that names them.
//
// A new method is one file plus one line: write
//   RoundSolverOutcome solve_mine(const RoundSolverProblem& p) { ... }
// in gmf/optimizers/mine.cpp (inside namespace hisnegs::gmf), add the file to
// gmf/CMakeLists.txt, and add the line
//   HISNEGS_OPTIMIZER("mine", solve_mine, "one line saying what it is")
// to gmf/optimizers.def. `compare-optimizers --optimizers adam,mine` then runs it
// from the same init, samples, loss and budget; gmf/optimizers/spectral_gradient.cpp
// is a complete example. Python callables take the same problem
// (hisnegs.compare_optimizers, docs/python.md).
#pragma once

#include <functional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include "gmf/gmf_options.hpp"
#include "gmf/objective.hpp"

namespace hisnegs::gmf {

// One round of the fit, as a solver sees it. The round loop builds it: the round's
// samples, their block index padded to the round's trust region, and the box.
struct RoundSolverProblem {
  // The round's parameters: 11·K doubles, Gaussian after Gaussian in the checkpoint's
  // order (gmf/core/param_layout.hpp). The solver moves them in place; what they hold when
  // it returns is the round's result (clamped into [lower, upper] by the loop).
  std::span<double> x;
  // The round's box (its trust region): every parameter stays within it. ±inf where
  // a parameter is free (the quaternion, the intensity logit).
  std::span<const double> lower, upper;
  // The stage-1 loss ½ Σ w² (f − V)² over the round's samples at the round's model
  // (aggregation and β), with its gradient: objective.evaluate(x, gradient). The same
  // function every built-in optimizer minimizes.
  const FitObjective& objective;
  // Limits: at most this many iterations, and the wall time left in the fit's budget
  // (seconds). The budget is the solver's to honour: log() returns true once the time
  // is spent, and the loop starts no round after it. Time a solver overruns counts
  // against it in compare-optimizers (its log lines carry the wall clock).
  int max_iterations = 0;
  double seconds_left = 0;
  // Call once per iteration with the loss at the iterate (objective's value at x, or
  // the value the solver just computed there). Every call is one log line (iteration,
  // wall clock, loss). Returns true when the solver must stop now: the time left is
  // spent or the loss reached gmf.stop_loss (compare-optimizers' target).
  std::function<bool(double loss)> log;
  // The fit's options (learning rate, axis ratio, ...) and the stack's frame (voxel size).
  const GmfOptions& options;
  const io::WorldFrame& frame;
};

// What a solver reports when it returns.
struct RoundSolverOutcome {
  int iterations = 0;      // iterations taken (log() calls, normally)
  bool converged = false;  // true: more iterations would not help (the loop may end the fit)
  std::string message;     // why it stopped, for the fit's stop reason
};

using RoundSolver = std::function<RoundSolverOutcome(const RoundSolverProblem&)>;

// A named optimizer of the registry (gmf/optimizers.def) or one given by code.
struct NamedSolver {
  std::string name;
  std::string description;
  RoundSolver solve;
};

// The optimizers of gmf/optimizers.def, in its order.
const std::vector<NamedSolver>& registered_optimizers();
// The registered optimizer called `name`, or nullptr.
const NamedSolver* find_registered_optimizer(std::string_view name);
// Their names, ", "-separated ("spg").
std::string registered_optimizer_names();

}  // namespace hisnegs::gmf
