// SPDX-License-Identifier: Apache-2.0
// compare_optimizers: Adam first (its loss after N steps is the target), then the
// others under the same budget; time to target read from each run's log.
#include "gmf/compare.hpp"

#include <algorithm>
#include <memory>
#include <new>
#include <stdexcept>
#include <string_view>
#include <type_traits>
#include <utility>

#include "io/config.hpp"
#include "io/error.hpp"

namespace hisnegs::gmf {

namespace {

// Calls f(text, value) for each configured name of an optimizer (GmfOptions' enum names).
template <class F>
void for_each_optimizer_name(F&& f) {
  GmfOptions o;
  o.visit([&](std::string_view key, auto& /*field*/, auto&&... names) {
    if constexpr (sizeof...(names) == 1) {
      if (key != "optimizer") return;
      for (const auto& [text, value] : (names, ...)) {
        if constexpr (std::is_same_v<std::decay_t<decltype(value)>, Optimizer>) f(std::string_view(text), value);
      }
    }
  });
}

}  // namespace

std::string optimizer_name(Optimizer optimizer) {
  std::string name;
  for_each_optimizer_name([&](std::string_view text, Optimizer value) {
    if (value == optimizer) name = std::string(text);
  });
  return name;
}

std::optional<Optimizer> find_builtin_optimizer(std::string_view name) {
  std::optional<Optimizer> found;
  for_each_optimizer_name([&](std::string_view text, Optimizer value) {
    if (text == name) found = value;
  });
  return found;
}

std::vector<Optimizer> builtin_optimizers(const std::vector<std::string>& names, std::string_view option) {
  std::vector<Optimizer> out;
  for (const std::string& name : names) {
    GmfOptions parsed;
    io::set_enum_field(parsed, "optimizer", name, option);  // its message lists the built-in names
    out.push_back(parsed.optimizer);
  }
  return out;
}

void add_optimizers(CompareOptions& options, const std::vector<std::string>& names, std::string_view option) {
  for (const std::string& name : names) {
    if (const NamedSolver* registered = find_registered_optimizer(name)) {
      options.custom.push_back(*registered);
      continue;
    }
    try {
      options.optimizers.push_back(builtin_optimizers({name}, option).front());
    } catch (const io::InputError& e) {
      throw io::InputError(std::string(e.what()) + ", or a registered one: " + registered_optimizer_names());
    }
  }
}

void CompareOptions::validate() const {
  if (optimizers.empty() && custom.empty()) throw io::InputError("compare-optimizers: no optimizers to compare");
  io::require_positive("compare", "time_budget_s", time_budget_s);
  io::require_in_range("compare", "adam_steps", adam_steps, 1, 1e9);
  for (const Optimizer o : continuation) {
    if (o != Optimizer::kAdam && o != Optimizer::kBrickLm) {
      io::fail_option("compare", "continuation", optimizer_name(o),
                      "only adam and brick-lm can follow the β schedule (they log at the final β)");
    }
  }
  for (std::size_t i = 0; i < custom.size(); ++i) {
    const std::string& name = custom[i].name;
    const bool builtin = find_builtin_optimizer(name).has_value();
    if (name.empty() || builtin || !custom[i].solve) {
      io::fail_option("compare", "optimizers", name,
                      name.empty() || !custom[i].solve ? "a custom optimizer needs a name and a solver"
                                                       : "a custom optimizer cannot take a built-in's name");
    }
    for (std::size_t j = 0; j < i; ++j) {
      if (custom[j].name == name) io::fail_option("compare", "optimizers", name, "named twice");
    }
  }
}

Comparison compare_optimizers(const io::Volume& volume, const SampleSet& samples, const io::WorldFrame& frame,
                              const GaussianMixture& initial, const GmfOptions& base, const CompareOptions& options,
                              const std::function<void(const OptimizerRun&, const FitIteration&)>& on_progress,
                              const std::function<void(const Comparison&)>& after_run) {
  options.validate();
  std::vector<Optimizer> order = options.optimizers;
  std::stable_partition(order.begin(), order.end(), [](Optimizer o) { return o == Optimizer::kAdam; });
  order.erase(std::unique(order.begin(), order.end()), order.end());

  // Built-in optimizers, then the custom ones (Optimizer::kCustom with their solver).
  std::vector<std::pair<Optimizer, std::shared_ptr<const NamedSolver>>> runs;
  runs.reserve(order.size() + options.custom.size());
  for (const Optimizer optimizer : order) runs.emplace_back(optimizer, nullptr);
  for (const NamedSolver& solver : options.custom) {
    runs.emplace_back(Optimizer::kCustom, std::make_shared<const NamedSolver>(solver));
  }

  Comparison comparison;
  for (const auto& [optimizer, solver] : runs) {
    GmfOptions o = base;
    o.optimizer = optimizer;
    o.custom = solver;
    o.densify = false;      // same K for everyone: the comparison is of optimizers, not of density control
    o.sample_jitter = 0.0;  // the same samples in every round and run: one objective, comparable losses
    o.time_budget_s = options.time_budget_s;
    o.rounds = 1000;  // rounds only rebuild the index here; the budget (or Adam's steps) ends the run
    // One objective for all, the softmax at the schedule's final β: the runs with
    // continuation follow the schedule towards it and log their loss at it.
    const bool continuation =
        std::find(options.continuation.begin(), options.continuation.end(), optimizer) != options.continuation.end() &&
        o.aggregation == Aggregation::kSoftmax && o.beta_start < o.beta_end;
    if (!continuation) o.beta_start = o.beta_end;
    o.report_beta = o.aggregation == Aggregation::kSoftmax ? o.beta_end : 0.0;
    o.hard_share = 0.0;  // the same objective to the end (a run's hard share would change it midway)
    // The global solvers' rounds are index rebuilds: 25 iterations each, as before
    // (brick LM's sweeps take gmf.brick_iterations per brick).
    o.iterations_per_round = 25;
    o.max_iterations = optimizer == Optimizer::kAdam ? options.adam_steps : 0;
    o.stop_loss = optimizer != Optimizer::kAdam && options.stop_at_target && comparison.target_loss > 0
                      ? comparison.target_loss
                      : 0.0;
    OptimizerRun run;
    run.optimizer = optimizer;
    run.name = solver ? solver->name : optimizer_name(optimizer);
    run.continuation = continuation;
    GaussianMixture mixture = initial;
    auto record = [&](const FitIteration& it) {
      run.result.log.push_back(it);
      if (on_progress) on_progress(run, it);
    };
    try {
      const FitResult result = fit_mixture(volume, samples, frame, mixture, o, record);
      run.result = result;
    } catch (const io::InputError&) {
      throw;
    } catch (const io::Interrupted&) {
      throw;
    } catch (const std::bad_alloc&) {
      run.failure = "out of memory";
    } catch (const std::exception& e) {
      run.failure = e.what();
    }
    if (!run.failure.empty()) {
      run.result.stop_reason = "failed: " + run.failure;
      run.result.seconds = run.result.log.empty() ? 0.0 : run.result.log.back().seconds;
    }
    const std::vector<FitIteration>& log = run.result.log;
    run.final_loss = log.empty() ? 0.0 : log.back().loss;
    run.iterations = log.empty() ? 0 : log.back().iteration;
    run.gaussians = static_cast<int>(mixture.size());
    if (optimizer == Optimizer::kAdam) {
      comparison.target_loss = run.final_loss;
      comparison.adam_steps_done = run.iterations;
    }
    if (comparison.target_loss > 0) {
      const auto hit = std::find_if(log.begin(), log.end(),
                                    [&](const FitIteration& it) { return it.loss <= comparison.target_loss; });
      if (hit != log.end()) run.seconds_to_target = hit->seconds;
    }
    comparison.runs.push_back(std::move(run));
    if (after_run) after_run(comparison);
  }
  return comparison;
}

}  // namespace hisnegs::gmf
