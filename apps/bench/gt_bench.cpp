// SPDX-License-Identifier: Apache-2.0
// Ground-truth ray-marching benchmarks: ms per view over the 30 evaluation views
// of a volume, exact and report mode, on the CPU back end and (when a device is
// present) CUDA. Reports the median per view as a counter.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <memory>
#include <numeric>

#include "apps/bench/benchmarks.hpp"
#include "io/load_volume.hpp"
#include "splat/backend.hpp"
#include "splat/ground_truth.hpp"
#include "splat/raymarch.hpp"

namespace hisnegs::apps::bench {

void register_gt_benchmarks(const std::filesystem::path& volume, int size) {
  // Loaded once, shared by every benchmark of the suite.
  auto loaded = std::make_shared<io::LoadedVolume>(io::load_volume(volume, io::VolumeOptions{}));
  const std::string name = volume.filename().string() + "/" + std::to_string(size);
  std::vector<splat::Backend> backends{splat::Backend::kCpu};
  if (splat::cuda_device_info().available) backends.push_back(splat::Backend::kCuda);
  for (const splat::Backend backend : backends) {
    for (const auto mode : {splat::RaymarchMode::kExact, splat::RaymarchMode::kReport}) {
      const std::string label = std::string("gt/") + std::string(splat::to_string(backend)) + "/" +
                                (mode == splat::RaymarchMode::kExact ? "exact/" : "report/") + name;
      benchmark::RegisterBenchmark(
          label.c_str(),
          [loaded, size, backend, mode](benchmark::State& state) {
            splat::CameraOptions co;
            co.width = co.height = size;
            const splat::CameraSet eval = splat::evaluation_orbit(co);
            splat::RaymarchOptions ro;
            ro.mode = mode;
            std::vector<double> per_view;
            for (auto _ : state) {
              // One iteration = the 30 evaluation views; the median view is the figure.
              const splat::MipStack stack =
                  splat::render_ground_truth(loaded->volume, loaded->frame, eval, ro, backend);
              per_view.insert(per_view.end(), stack.seconds_per_view.begin(), stack.seconds_per_view.end());
              state.SetIterationTime(
                  std::accumulate(stack.seconds_per_view.begin(), stack.seconds_per_view.end(), 0.0));
            }
            std::sort(per_view.begin(), per_view.end());
            state.counters["median_ms_per_view"] = 1e3 * per_view[per_view.size() / 2];
            state.counters["max_ms_per_view"] = 1e3 * per_view.back();
            state.counters["views"] = static_cast<double>(per_view.size());
          })
          ->Unit(benchmark::kMillisecond)
          ->UseManualTime()
          ->Iterations(2);
    }
  }
}

}  // namespace hisnegs::apps::bench
