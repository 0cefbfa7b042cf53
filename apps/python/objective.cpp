// SPDX-License-Identifier: Apache-2.0
// hisnegs._hisnegs, part two: the stage-1 objective (hisnegs.Objective) and
// optimizers written in Python (hisnegs.RoundProblem, compare_optimizers with
// callables), run from the same init, samples and budget as the built-in ones.
#include <algorithm>
#include <cmath>
#include <cstring>
#include <exception>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "apps/pipeline/fit_stage.hpp"
#include "apps/pipeline/optimizer_comparison.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/python/bindings.hpp"
#include "gmf/block_index.hpp"
#include "gmf/compare.hpp"
#include "gmf/fit.hpp"
#include "gmf/objective.hpp"
#include "gmf/round_solver.hpp"
#include "io/error.hpp"

namespace hisnegs::python {

// ---- the stage-1 objective --------------------------------------------------------

// value, gradient and value_and_gradient of a flat float64 x of size() values over
// Derived's `double evaluate(const double* x, double* gradient)`, and the check of
// such an x (io::InputError naming Derived::kName): shared by Objective and
// RoundProblem.
template <class Derived>
class GradientCalls {
 public:
  double value(const DoubleArray& x) { return self().evaluate(checked(x), nullptr); }
  py::array_t<double> gradient(const DoubleArray& x) {
    py::array_t<double> g(static_cast<py::ssize_t>(self().size()));
    self().evaluate(checked(x), g.mutable_data());
    return g;
  }
  py::tuple value_and_gradient(const DoubleArray& x) {
    py::array_t<double> g(static_cast<py::ssize_t>(self().size()));
    const double v = self().evaluate(checked(x), g.mutable_data());
    return py::make_tuple(v, g);
  }

 protected:
  // x's values, once it is a flat array of size() finite values whose quaternions
  // are not zero (scipy's line searches try such points; they crashed the index).
  const double* checked(const DoubleArray& x) const {
    const std::size_t n = static_cast<const Derived&>(*this).size();
    if (x.ndim() != 1 || static_cast<std::size_t>(x.size()) != n) {
      throw io::InputError(std::string(Derived::kName) + ": x must be a flat array of 11 K = " + std::to_string(n) +
                           " values (got " + std::to_string(x.size()) + ")");
    }
    const double* p = x.data();
    constexpr std::size_t kP = gmf::kGaussianParamCount;
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(p[i])) {
        throw io::InputError(std::string(Derived::kName) + ": x[" + std::to_string(i) + "] (Gaussian " +
                             std::to_string(i / kP) + ", parameter " + std::to_string(i % kP) + ") is " +
                             std::to_string(p[i]) + ", not a finite value");
      }
    }
    for (std::size_t k = 0; k < n / kP; ++k) {
      const double* q = p + kP * k + gmf::kRotW;
      if (q[0] == 0.0 && q[1] == 0.0 && q[2] == 0.0 && q[3] == 0.0) {
        throw io::InputError(std::string(Derived::kName) + ": Gaussian " + std::to_string(k) +
                             "'s quaternion (x[" + std::to_string(kP * k + gmf::kRotW) + "..]) is zero");
      }
    }
    return p;
  }

 private:
  Derived& self() { return static_cast<Derived&>(*this); }
};

// The fit's least-squares problem on a volume: its samples and weights (the sparse
// grid with gmf.background_fraction, at the voxel centres), the model's mixture as
// the size of x, and the mixture model (aggregation, β, cutoff). The block index is
// rebuilt for each new x, so x may move anywhere.
class Objective : public GradientCalls<Objective> {
 public:
  static constexpr const char* kName = "hisnegs.Objective";
  Objective(const Volume& volume, const Model& model, const std::string& config_text, const std::string& aggregation,
            double beta) {
    const AppConfig config = config_of(config_text, "hisnegs.Objective() options");
    gmf::GmfOptions gmf = config.gmf;
    if (aggregation != "softmax" && aggregation != "sum" && aggregation != "max") {
      throw io::InputError("hisnegs.Objective: aggregation '" + aggregation + "'; expected softmax | sum | max");
    }
    if (!(beta > 0) || !std::isfinite(beta)) throw io::InputError("hisnegs.Objective: beta must be > 0");
    model_.aggregation = aggregation == "sum"   ? gmf::Aggregation::kSum
                         : aggregation == "max" ? gmf::Aggregation::kMax
                                                : gmf::Aggregation::kSoftmax;
    model_.beta = beta;
    model_.cutoff = gmf.mahalanobis_cutoff;
    gaussians_ = model.checkpoint.mixture.size();
    if (gaussians_ == 0) throw io::InputError("hisnegs.Objective: the model has no Gaussians");
    const std::span<const float> params = gmf::flat_params(model.checkpoint.mixture);
    if (const std::string bad = gmf::describe_non_finite<float>(params, "value"); !bad.empty()) {
      throw io::InputError("hisnegs.Objective: the model's " + bad + " is not finite");
    }
    frame_ = volume.loaded.frame;
    py::gil_scoped_release release;
    io::SparseGridOptions sparse = config.sparse_grid;
    sparse.background_fraction = gmf.background_fraction;
    const io::SparseGrid grid = io::build_sparse_grid(volume.loaded.volume, frame_.aspect(), sparse);
    samples_ = gmf::fit_samples(grid, gmf);
  }
  [[nodiscard]] std::size_t size() const { return gmf::kGaussianParamCount * gaussians_; }
  [[nodiscard]] std::size_t samples() const { return samples_.size(); }

  py::array_t<double> residuals(const DoubleArray& x) {
    const gmf::SampleResiduals r = sample_residuals(x, false);
    return py::array_t<double>(static_cast<py::ssize_t>(r.residuals.size()), r.residuals.data());
  }
  // (values, column indices, row starts) of the Jacobian's CSR form.
  py::tuple jacobian(const DoubleArray& x) {
    const gmf::SampleResiduals r = sample_residuals(x, true);
    return py::make_tuple(py::array_t<double>(static_cast<py::ssize_t>(r.values.size()), r.values.data()),
                          py::array_t<std::int64_t>(static_cast<py::ssize_t>(r.columns.size()), r.columns.data()),
                          py::array_t<std::int64_t>(static_cast<py::ssize_t>(r.row_begin.size()), r.row_begin.data()));
  }
  // The loss at p (11 K values) and, when not null, its gradient.
  double evaluate(const double* p, double* gradient) {
    py::gil_scoped_release release;
    const gmf::BlockIndex index = index_at(p);
    const gmf::FitObjective objective(samples_, index, gaussians_, model_);
    return objective.evaluate(p, gradient);
  }

 private:
  // Which Gaussians may reach which sample blocks at x (rebuilt for every x).
  [[nodiscard]] gmf::BlockIndex index_at(const double* p) const {
    const std::vector<float> rounded(p, p + size());
    return gmf::build_block_index(gmf::mixture_from_flat(rounded), samples_, frame_, model_.cutoff);
  }
  gmf::SampleResiduals sample_residuals(const DoubleArray& x, bool with_jacobian) {
    const double* p = checked(x);
    py::gil_scoped_release release;
    return gmf::sample_residuals(samples_, index_at(p), model_, p, with_jacobian);
  }

  gmf::MixtureModel model_;
  std::size_t gaussians_ = 0;
  io::WorldFrame frame_;
  gmf::SampleSet samples_;
};

// ---- bring your own optimizer ----------------------------------------------------

// Raised by RoundProblem.iterate when the round must end (hisnegs.StopRound).
struct StopRound : std::runtime_error {
  StopRound() : std::runtime_error("the round's time is spent or the loss reached the target") {}
};

// A Python exception raised inside a C++ call that records failures and goes on
// (the comparison): kept here, passed up as io::Interrupted, raised again at the
// binding's boundary (rethrow_pending). Guarded by the GIL.
std::exception_ptr& pending_python_error() {
  static std::exception_ptr pending;
  return pending;
}

[[noreturn]] void defer_python_error() {
  pending_python_error() = std::current_exception();
  throw io::Interrupted("a Python exception stopped the call");
}

void rethrow_pending() {
  std::exception_ptr e = std::exchange(pending_python_error(), nullptr);
  if (e) std::rethrow_exception(e);
}

// Progress lines for calls that record failures: a Python exception (Ctrl-C) is deferred.
apps::Progress deferring_progress(const std::optional<py::function>& callback) {
  apps::Progress p;
  p.line = [callback](std::string_view line) {
    py::gil_scoped_acquire gil;
    try {
      if (callback) (*callback)(std::string(line));
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    } catch (const py::error_already_set&) {
      defer_python_error();
    }
  };
  return p;
}

// hisnegs.RoundProblem: one round of the stage-1 fit as a Python optimizer sees it
// (gmf::RoundSolverProblem). Valid only during the optimizer's call.
class RoundProblem : public GradientCalls<RoundProblem> {
 public:
  static constexpr const char* kName = "hisnegs.RoundProblem";
  explicit RoundProblem(const gmf::RoundSolverProblem& p)
      : p_(&p), last_x_(p.x.begin(), p.x.end()), iterate_(p.x.begin(), p.x.end()) {}

  [[nodiscard]] std::size_t size() const { return problem().x.size(); }
  py::array_t<double> x() const { return copy_of(problem().x); }
  py::array_t<double> lower() const { return copy_of(problem().lower); }
  py::array_t<double> upper() const { return copy_of(problem().upper); }
  // scipy's bounds: (lower, upper) pairs, None where unbounded.
  py::list bounds() const {
    const auto& p = problem();
    py::list out;
    for (std::size_t i = 0; i < p.x.size(); ++i) {
      out.append(py::make_tuple(std::isfinite(p.lower[i]) ? py::cast(p.lower[i]) : py::none(),
                                std::isfinite(p.upper[i]) ? py::cast(p.upper[i]) : py::none()));
    }
    return out;
  }
  [[nodiscard]] int max_iterations() const { return problem().max_iterations; }
  [[nodiscard]] double seconds_left() const { return problem().seconds_left; }
  [[nodiscard]] int iterations() const { return iterations_; }

  // The round's loss at p (size() values) and, when not null, its gradient; p
  // becomes the last point evaluated (iterate() logs it without evaluating again).
  double evaluate(const double* p, double* gradient) {
    const gmf::FitObjective& objective = problem().objective;
    double loss = 0;
    {
      py::gil_scoped_release release;
      loss = objective.evaluate(p, gradient);
    }
    std::copy(p, p + size(), last_x_.begin());
    last_loss_ = loss;
    has_last_ = true;
    return loss;
  }
  // One iteration ends at x: its loss is logged (the last evaluation's when it was
  // at x, else a new one) and x becomes the round's result so far. Raises
  // StopRound when the round must end.
  void iterate(const DoubleArray& x) {
    const double* p = checked(x);
    const bool known = has_last_ && std::memcmp(p, last_x_.data(), size() * sizeof(double)) == 0;
    const double loss = known ? last_loss_ : evaluate(p, nullptr);
    std::copy(p, p + size(), iterate_.begin());
    log(loss);
  }
  // The round's start, logged as every built-in optimizer logs it (iteration 0).
  void start() { log(evaluate(problem().x.data(), nullptr)); }
  // Where the round ends: `result` (the optimizer's return value) or, for None or a
  // StopRound, the last iterate.
  void finish(const py::object& result) {
    const auto& p = problem();
    if (!result.is_none()) {
      const DoubleArray r = DoubleArray::ensure(result);
      if (!r || r.ndim() != 1 || static_cast<std::size_t>(r.size()) != size()) {
        throw io::InputError("hisnegs.compare_optimizers: an optimizer returned something other than a flat array "
                             "of 11 K = " + std::to_string(size()) + " floats (or None)");
      }
      std::copy(r.data(), r.data() + size(), p.x.begin());
    } else {
      std::copy(iterate_.begin(), iterate_.end(), p.x.begin());
    }
  }
  void close() { p_ = nullptr; }

 private:
  const gmf::RoundSolverProblem& problem() const {
    if (p_ == nullptr) throw io::InputError("hisnegs.RoundProblem: used after its round ended");
    return *p_;
  }
  static py::array_t<double> copy_of(std::span<const double> v) {
    return py::array_t<double>(static_cast<py::ssize_t>(v.size()), v.data());
  }
  void log(double loss) {
    ++iterations_;
    const bool stop = problem().log(loss);
    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    if (stop) throw StopRound();
  }

  const gmf::RoundSolverProblem* p_;
  std::vector<double> last_x_, iterate_;
  double last_loss_ = 0;
  bool has_last_ = false;
  int iterations_ = 0;
};

// A Python callable as a round solver: called once per round with a RoundProblem.
gmf::NamedSolver python_solver(const std::string& name, const py::function& callable) {
  gmf::NamedSolver solver;
  solver.name = name;
  solver.description = "a Python callable";
  solver.solve = [name, callable](const gmf::RoundSolverProblem& p) {
    py::gil_scoped_acquire gil;
    auto problem = std::make_shared<RoundProblem>(p);
    gmf::RoundSolverOutcome out;
    try {
      problem->start();
      problem->finish(callable(problem));
      out.message = name + ": returned";
    } catch (const StopRound&) {
      problem->finish(py::none());
      out.message = name + ": stopped for time or at the target";
    } catch (py::error_already_set& e) {
      if (!e.matches(py::module_::import("hisnegs._hisnegs").attr("StopRound"))) {
        problem->close();
        defer_python_error();  // the optimizer's own error (or Ctrl-C): raised again by compare_optimizers
      }
      problem->finish(py::none());
      out.message = name + ": stopped for time or at the target";
    }
    out.iterations = problem->iterations();
    problem->close();
    return out;
  };
  return solver;
}

py::dict compare_optimizers(const Volume& volume, const std::vector<std::string>& builtins, const py::dict& custom,
                            const std::string& config_text, double budget_s, int adam_steps, bool stop_at_target,
                            const std::vector<std::string>& continuation, const std::string& output,
                            const std::optional<py::function>& progress) {
  const AppConfig config = config_of(config_text, "hisnegs.compare_optimizers() options");
  gmf::CompareOptions options;
  options.time_budget_s = budget_s;
  options.adam_steps = adam_steps;
  options.stop_at_target = stop_at_target;
  options.optimizers.clear();
  gmf::add_optimizers(options, builtins, "hisnegs.compare_optimizers builtins");
  options.continuation = gmf::builtin_optimizers(continuation, "hisnegs.compare_optimizers continuation");
  for (const auto& [key, value] : custom) {
    const std::string name = py::str(key);
    if (!PyCallable_Check(value.ptr())) {
      throw io::InputError("hisnegs.compare_optimizers: optimizers['" + name + "'] is not callable");
    }
    options.custom.push_back(python_solver(name, py::reinterpret_borrow<py::function>(value)));
  }
  options.validate();
  const apps::Progress sink = deferring_progress(progress);
  gmf::Comparison c;
  try {
    py::gil_scoped_release release;
    const apps::FitConfig fit_config(config);
    const apps::FitSetup setup =
        apps::prepare_fit(volume.loaded, volume.loaded.volume.source, fit_config, "compare", sink);
    c = apps::compare_prepared(setup, volume.loaded.volume.source, fit_config, options, output, sink);
  } catch (const io::Interrupted&) {
    rethrow_pending();
    throw;
  }
  py::list runs;
  for (const gmf::OptimizerRun& run : c.runs) {
    py::dict r;
    r["name"] = run.name;
    r["seconds_to_target"] = run.seconds_to_target >= 0 ? py::cast(run.seconds_to_target) : py::none();
    r["final_loss"] = run.final_loss;
    r["final_psnr_3d"] = run.failure.empty() ? py::cast(run.result.final_psnr_3d) : py::none();
    r["iterations"] = run.iterations;
    r["seconds"] = run.result.seconds;
    r["gaussians"] = run.gaussians;
    r["stop_reason"] = run.result.stop_reason;
    r["continuation"] = run.continuation;
    r["failure"] = run.failure;
    std::vector<double> seconds, loss;
    std::vector<int> iteration;
    for (const gmf::FitIteration& it : run.result.log) {
      if (it.psnr_3d >= 0) continue;  // the final measurement line repeats the last loss
      seconds.push_back(it.seconds);
      loss.push_back(it.loss);
      iteration.push_back(it.iteration);
    }
    py::dict curve;
    curve["seconds"] = py::array_t<double>(static_cast<py::ssize_t>(seconds.size()), seconds.data());
    curve["loss"] = py::array_t<double>(static_cast<py::ssize_t>(loss.size()), loss.data());
    curve["iteration"] = py::array_t<int>(static_cast<py::ssize_t>(iteration.size()), iteration.data());
    r["curve"] = curve;
    runs.append(r);
  }
  py::dict out;
  out["target_loss"] = c.target_loss > 0 ? py::cast(c.target_loss) : py::none();
  out["adam_steps_done"] = c.adam_steps_done;
  out["runs"] = runs;
  return out;
}


void bind_objective(py::module_& m) {
  py::register_exception<StopRound>(m, "StopRound");
  py::class_<RoundProblem, std::shared_ptr<RoundProblem>>(m, "RoundProblem")
      .def_property_readonly("size", &RoundProblem::size)
      .def_property_readonly("x", &RoundProblem::x)
      .def_property_readonly("lower", &RoundProblem::lower)
      .def_property_readonly("upper", &RoundProblem::upper)
      .def_property_readonly("bounds", &RoundProblem::bounds)
      .def_property_readonly("max_iterations", &RoundProblem::max_iterations)
      .def_property_readonly("seconds_left", &RoundProblem::seconds_left)
      .def_property_readonly("iterations", &RoundProblem::iterations)
      .def("value", &RoundProblem::value)
      .def("gradient", &RoundProblem::gradient)
      .def("value_and_gradient", &RoundProblem::value_and_gradient)
      .def("iterate", &RoundProblem::iterate);
  m.def("_compare_optimizers", &compare_optimizers);

  py::class_<Objective>(m, "_Objective")
      .def(py::init<const Volume&, const Model&, const std::string&, const std::string&, double>())
      .def_property_readonly("size", &Objective::size)
      .def_property_readonly("samples", &Objective::samples)
      .def("value", &Objective::value)
      .def("gradient", &Objective::gradient)
      .def("value_and_gradient", &Objective::value_and_gradient)
      .def("residuals", &Objective::residuals)
      .def("jacobian", &Objective::jacobian);
}

}  // namespace hisnegs::python
