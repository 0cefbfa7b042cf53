// SPDX-License-Identifier: Apache-2.0
// `spg`: the spectral projected gradient method (Birgin, Martínez & Raydan 2000),
// monotone variant. Each iteration steps along −g with the Barzilai–Borwein length
// sᵀs / sᵀy of the last move, projects onto the round's box, and halves the step
// until the loss decreases (Armijo on the projected step). It needs nothing but the
// loss and its gradient: the example of gmf/round_solver.hpp's interface, and a
// first-order baseline between L-BFGS and Adam in compare-optimizers.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "gmf/round_solver.hpp"

namespace hisnegs::gmf {

RoundSolverOutcome solve_spectral_gradient(const RoundSolverProblem& p) {
  constexpr double kArmijo = 1e-4;      // sufficient decrease, as a fraction of gᵀd
  constexpr int kBacktracks = 30;       // halvings before the round gives up
  constexpr double kStepMin = 1e-12, kStepMax = 1e12;
  const std::size_t n = p.x.size();
  std::vector<double> g(n), x_new(n), g_new(n);
  double* x = p.x.data();
  const auto project = [&](std::vector<double>& v) {
    for (std::size_t i = 0; i < n; ++i) v[i] = std::clamp(v[i], p.lower[i], p.upper[i]);
  };
  double loss = p.objective.evaluate(x, g.data());
  // First step: one that moves the largest gradient component by 1e-3 (world units or log-scale).
  double g_max = 0;
  for (const double v : g) g_max = std::max(g_max, std::abs(v));
  double step = g_max > 0 ? 1e-3 / g_max : 1.0;
  RoundSolverOutcome out;
  for (; out.iterations < p.max_iterations; ++out.iterations) {
    if (!std::isfinite(loss)) throw std::runtime_error("spg: the loss is not finite");
    if (p.log(loss)) {
      out.message = "spg: stopped by the loop (time or target)";
      return out;
    }
    double slope = 0, loss_new = 0;
    int halvings = 0;
    for (;; ++halvings) {
      for (std::size_t i = 0; i < n; ++i) x_new[i] = x[i] - step * g[i];
      project(x_new);
      slope = 0;
      for (std::size_t i = 0; i < n; ++i) slope += g[i] * (x_new[i] - x[i]);
      loss_new = p.objective.evaluate(x_new.data(), g_new.data());
      if (slope >= 0 || (std::isfinite(loss_new) && loss_new <= loss + kArmijo * slope)) break;
      if (halvings == kBacktracks) break;
      step *= 0.5;
    }
    if (slope >= 0 || halvings == kBacktracks) {
      out.converged = true;
      out.message = "spg: no descent along the projected gradient";
      return out;
    }
    double ss = 0, sy = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double s = x_new[i] - x[i], y = g_new[i] - g[i];
      ss += s * s;
      sy += s * y;
    }
    step = sy > 0 ? std::clamp(ss / sy, kStepMin, kStepMax) : kStepMax;
    std::copy(x_new.begin(), x_new.end(), x);
    g.swap(g_new);
    loss = loss_new;
  }
  out.message = "spg: " + std::to_string(out.iterations) + " iterations";
  return out;
}

}  // namespace hisnegs::gmf
