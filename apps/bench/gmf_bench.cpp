// SPDX-License-Identifier: Apache-2.0
// GMF benchmarks: one residual block (64 samples, 24 Gaussians, the size of a
// dense 4^3 block) evaluated with its Jacobian three ways (gmf/jacobian_probe.hpp):
// the analytic BlockCost, Ceres' central numeric differences and automatic
// differentiation over the same templated residuals.
#include <benchmark/benchmark.h>

#include <memory>

#include "apps/bench/benchmarks.hpp"
#include "gmf/jacobian_probe.hpp"

namespace hisnegs::apps::bench {
namespace {

void run(benchmark::State& state, gmf::JacobianMethod method) {
  gmf::JacobianProbe probe(64, 24, method);
  for (auto _ : state) benchmark::DoNotOptimize(probe.evaluate());
  state.counters["residuals"] = probe.residuals();
  state.counters["parameters"] = probe.parameters();
}

}  // namespace

void register_gmf_benchmarks() {
  benchmark::RegisterBenchmark("gmf/residual_block/analytic", [](benchmark::State& s) {
    run(s, gmf::JacobianMethod::kAnalytic);
  })->Unit(benchmark::kMicrosecond);
  benchmark::RegisterBenchmark("gmf/residual_block/numeric_central", [](benchmark::State& s) {
    run(s, gmf::JacobianMethod::kNumericCentral);
  })->Unit(benchmark::kMicrosecond);
  benchmark::RegisterBenchmark("gmf/residual_block/autodiff", [](benchmark::State& s) {
    run(s, gmf::JacobianMethod::kAutoDiff);
  })->Unit(benchmark::kMicrosecond);
}

}  // namespace hisnegs::apps::bench
