// SPDX-License-Identifier: Apache-2.0
// Splatting benchmarks (report Tables 7, 9, 11): ms per frame of hard MIP, soft-MIP
// forward and soft-MIP backward against resolution and against K, soft-MIP against
// β, on synthetic mixtures shaped like Table 3, over the 30 evaluation views; CPU
// and (when present) CUDA. One iteration = one frame; counters give the median.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <memory>
#include <string>
#include <vector>

#include "apps/bench/benchmarks.hpp"
#include "io/timer.hpp"
#include "splat/render_views.hpp"
#include "splat/synthetic_mixture.hpp"

namespace hisnegs::apps::bench {
namespace {

enum class Pass { kHard, kSoft, kBackward };

const char* pass_name(Pass p) { return p == Pass::kHard ? "hard" : p == Pass::kSoft ? "soft" : "soft_backward"; }

void register_case(const std::string& label, const std::shared_ptr<const gmf::GaussianMixture>& mixture, int size,
                   splat::Backend backend, Pass pass, float beta) {
  benchmark::RegisterBenchmark(label.c_str(),
                               [=](benchmark::State& state) {
                                 splat::CameraOptions co;
                                 co.width = co.height = size;
                                 const splat::CameraSet eval = splat::evaluation_orbit(co);
                                 auto renderer = splat::make_splat_renderer(backend);
                                 splat::SplatSettings settings;
                                 settings.mode = pass == Pass::kHard ? splat::MipMode::kMax : splat::MipMode::kSoftmax;
                                 settings.beta = beta;
                                 const auto params = splat::flat_params(*mixture);
                                 std::vector<float> image(static_cast<std::size_t>(size) * size);
                                 std::vector<float> dL_dI(image.size(), 1e-3f), grad(params.size());
                                 auto frame = [&](std::size_t i) {
                                   const splat::CameraView& view = eval.views[i % eval.views.size()];
                                   renderer->forward(params, eval.intrinsics, view, settings, image);
                                   if (pass != Pass::kBackward) return 0.0;
                                   io::Stopwatch watch;  // backward alone: its forward is the one just run
                                   renderer->backward(dL_dI, grad);
                                   return watch.elapsed();
                                 };
                                 for (std::size_t i = 0; i < 3; ++i) frame(i);  // warm-up: buffers sized, caches filled
                                 std::vector<double> ms;
                                 std::int64_t visible = 0;
                                 std::size_t i = 0;
                                 for (auto _ : state) {
                                   io::Stopwatch watch;
                                   const double backward_s = frame(i++);
                                   const double s = pass == Pass::kBackward ? backward_s : watch.elapsed();
                                   state.SetIterationTime(s);
                                   ms.push_back(1e3 * s);
                                   visible += renderer->stats().visible;
                                 }
                                 std::sort(ms.begin(), ms.end());
                                 state.counters["median_ms"] = ms[ms.size() / 2];
                                 state.counters["p95_ms"] = ms[std::min(ms.size() - 1, ms.size() * 95 / 100)];
                                 state.counters["K"] = static_cast<double>(mixture->size());
                                 state.counters["visible"] =
                                     static_cast<double>(visible) / static_cast<double>(ms.size());
                               })
      ->Unit(benchmark::kMillisecond)
      ->UseManualTime()
      ->MinTime(0.5);
}

}  // namespace

void register_render_benchmarks(const std::vector<int>& sizes, const std::vector<int>& gaussian_counts,
                                const std::vector<float>& betas) {
  std::vector<splat::Backend> backends{splat::Backend::kCpu};
  if (splat::cuda_device_info().available) backends.push_back(splat::Backend::kCuda);
  auto mixture_of = [](int K) {
    splat::SyntheticMixtureOptions o;
    o.gaussians = K;
    return std::make_shared<const gmf::GaussianMixture>(splat::make_synthetic_mixture(o));
  };
  const int K_default = 50000;
  auto base = mixture_of(K_default);
  for (const splat::Backend backend : backends) {
    const std::string be = std::string(splat::to_string(backend));
    // Table 7: against resolution at K = 50k.
    for (int size : sizes) {
      for (Pass pass : {Pass::kHard, Pass::kSoft, Pass::kBackward}) {
        register_case("render/" + be + "/" + pass_name(pass) + "/K50000/" + std::to_string(size), base, size, backend,
                      pass, 50.0f);
      }
    }
    // Table 9: against K at 256².
    for (int K : gaussian_counts) {
      auto m = K == K_default ? base : mixture_of(K);
      for (Pass pass : {Pass::kHard, Pass::kSoft}) {
        register_case("render/" + be + "/" + pass_name(pass) + "/K" + std::to_string(K) + "/256", m, 256, backend, pass,
                      50.0f);
      }
    }
    // Table 11: soft-MIP against β at 256², K = 50k (hard MIP is in the resolution rows).
    for (float beta : betas) {
      register_case("render/" + be + "/soft_beta" + std::to_string(static_cast<int>(beta)) + "/K50000/256", base, 256,
                    backend, Pass::kSoft, beta);
    }
  }
}

}  // namespace hisnegs::apps::bench
