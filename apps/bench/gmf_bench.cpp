// SPDX-License-Identifier: Apache-2.0
// GMF benchmarks: one residual block (64 samples, 24 Gaussians, the size of a
// dense 4^3 block) evaluated with its Jacobian three ways (gmf/jacobian_probe.hpp):
// the analytic BlockCost, Ceres' central numeric differences and automatic
// differentiation over the same templated residuals. With a stack and a model:
// the whole stage-1 objective's value and gradient at the model (what
// hisnegs.Objective.gradient computes per call, for the binding's overhead).
#include <benchmark/benchmark.h>

#include <memory>
#include <vector>

#include "apps/bench/benchmarks.hpp"
#include "gmf/block_index.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/fit.hpp"
#include "gmf/jacobian_probe.hpp"
#include "gmf/objective.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"

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

void register_objective_benchmark(const std::filesystem::path& volume_path, const std::filesystem::path& model_path,
                                  const io::VolumeOptions& volume_options, const io::SparseGridOptions& sparse_grid,
                                  const gmf::GmfOptions& gmf) {
  benchmark::RegisterBenchmark("gmf/objective_gradient", [=](benchmark::State& state) {
    const io::LoadedVolume loaded = io::load_volume(volume_path, volume_options);
    io::SparseGridOptions sparse = sparse_grid;
    sparse.background_fraction = gmf.background_fraction;
    const gmf::SampleSet samples =
        gmf::fit_samples(io::build_sparse_grid(loaded.volume, loaded.frame.aspect(), sparse), gmf);
    const gmf::Checkpoint checkpoint = gmf::load_checkpoint(model_path);
    const gmf::MixtureModel model = gmf::model_of(checkpoint.meta, gmf.mahalanobis_cutoff);
    const auto flat = gmf::flat_params(checkpoint.mixture);
    const std::vector<double> x(flat.begin(), flat.end());
    std::vector<double> g(x.size());
    for (auto _ : state) {
      // As hisnegs.Objective per call: the index at x (from x rounded to float), then value and gradient.
      const std::vector<float> rounded(x.begin(), x.end());
      const gmf::BlockIndex index =
          gmf::build_block_index(gmf::mixture_from_flat(rounded), samples, loaded.frame, model.cutoff);
      const gmf::FitObjective objective(samples, index, checkpoint.mixture.size(), model);
      benchmark::DoNotOptimize(objective.evaluate(x.data(), g.data()));
    }
    state.counters["gaussians"] = static_cast<double>(checkpoint.mixture.size());
    state.counters["samples"] = static_cast<double>(samples.size());
  })->Unit(benchmark::kMillisecond)->UseRealTime();
}

}  // namespace hisnegs::apps::bench
