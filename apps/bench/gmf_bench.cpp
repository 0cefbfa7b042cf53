// GMF benchmarks: one residual block (64 samples, 24 Gaussians, the size of a
// dense 4^3 block) evaluated with its Jacobian three ways: the analytic
// BrickCost, Ceres' DynamicNumericDiffCostFunction (central differences) and
// DynamicAutoDiffCostFunction (Jets) over the same templated residuals.
#include <benchmark/benchmark.h>
#include <ceres/dynamic_autodiff_cost_function.h>
#include <ceres/dynamic_numeric_diff_cost_function.h>

#include <memory>
#include <random>

#include "apps/bench/benchmarks.hpp"
#include "gmf/detail/brick_cost.hpp"

namespace hisnegs::apps::bench {
namespace {

struct BlockFixture {
  gmf::SampleSet samples;
  std::vector<std::array<double, 11>> params;
  std::vector<double*> blocks;
  std::vector<std::uint32_t> ids;

  BlockFixture(int n_samples, int n_gaussians) {
    std::mt19937_64 rng(1);
    std::uniform_real_distribution<double> u(-1, 1), v(0, 1);
    samples.brick_begin = {0, static_cast<std::uint32_t>(n_samples)};
    samples.brick_origin = {{0, 0, 0}};
    samples.block = 4;
    for (int i = 0; i < n_samples; ++i) {
      samples.x.push_back(0.02 * u(rng));
      samples.y.push_back(0.02 * u(rng));
      samples.z.push_back(0.02 * u(rng));
      samples.value.push_back(v(rng));
      samples.weight.push_back(1.0);
    }
    params.resize(n_gaussians);
    for (auto& p : params) {
      for (int a = 0; a < 3; ++a) p[gmf::kMeanX + a] = 0.03 * u(rng);
      for (int a = 0; a < 3; ++a) p[gmf::kLogScale0 + a] = std::log(0.01 + 0.01 * v(rng));
      for (int a = 0; a < 4; ++a) p[gmf::kRotW + a] = u(rng) + (a == 0 ? 1.5 : 0.0);
      p[gmf::kLogit] = u(rng);
    }
    for (auto& p : params) {
      blocks.push_back(&p[gmf::kMeanX]);
      blocks.push_back(&p[gmf::kLogScale0]);
      blocks.push_back(&p[gmf::kRotW]);
      blocks.push_back(&p[gmf::kLogit]);
    }
    for (int k = 0; k < n_gaussians; ++k) ids.push_back(static_cast<std::uint32_t>(k));
  }
};

struct ResidualsOnly {
  const gmf::detail::BrickCost* cost;
  bool operator()(double const* const* p, double* r) const { return cost->Evaluate(p, r, nullptr); }
};

void run(benchmark::State& state, const ceres::CostFunction& cost, const BlockFixture& f) {
  const int nr = cost.num_residuals();
  std::vector<std::vector<double>> J;
  std::vector<double*> jac;
  for (int size : cost.parameter_block_sizes()) {
    J.emplace_back(static_cast<std::size_t>(nr) * size);
    jac.push_back(J.back().data());
  }
  std::vector<double> r(nr);
  for (auto _ : state) {
    cost.Evaluate(f.blocks.data(), r.data(), jac.data());
    benchmark::DoNotOptimize(r.data());
  }
  state.counters["residuals"] = nr;
  state.counters["parameters"] = static_cast<double>(f.params.size() * 11);
}

}  // namespace

void register_gmf_benchmarks() {
  auto fixture = std::make_shared<BlockFixture>(64, 24);
  auto analytic = std::make_shared<gmf::detail::BrickCost>(fixture->samples, 0, fixture->ids, 16.0);
  benchmark::RegisterBenchmark("gmf/residual_block/analytic", [fixture, analytic](benchmark::State& s) {
    run(s, *analytic, *fixture);
  })->Unit(benchmark::kMicrosecond);
  benchmark::RegisterBenchmark("gmf/residual_block/numeric_central", [fixture, analytic](benchmark::State& s) {
    ceres::DynamicNumericDiffCostFunction<ResidualsOnly, ceres::CENTRAL> numeric(new ResidualsOnly{analytic.get()});
    for (int size : analytic->parameter_block_sizes()) numeric.AddParameterBlock(size);
    numeric.SetNumResiduals(analytic->num_residuals());
    run(s, numeric, *fixture);
  })->Unit(benchmark::kMicrosecond);
  benchmark::RegisterBenchmark("gmf/residual_block/autodiff", [fixture, analytic](benchmark::State& s) {
    auto* functor = new gmf::detail::BrickResiduals{&fixture->samples, 0, 64, fixture->params.size(), 16.0};
    ceres::DynamicAutoDiffCostFunction<gmf::detail::BrickResiduals, 4> autodiff(functor);
    for (int size : analytic->parameter_block_sizes()) autodiff.AddParameterBlock(size);
    autodiff.SetNumResiduals(analytic->num_residuals());
    run(s, autodiff, *fixture);
  })->Unit(benchmark::kMicrosecond);
}

}  // namespace hisnegs::apps::bench
