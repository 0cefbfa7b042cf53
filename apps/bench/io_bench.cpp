// SPDX-License-Identifier: Apache-2.0
// io benchmarks: TIFF read, read + normalize, sparse grid build, .vdb write.
#include <benchmark/benchmark.h>

#include "apps/bench/benchmarks.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"
#include "io/tiff_stack.hpp"

namespace hisnegs::apps::bench {

void register_io_benchmarks(const std::filesystem::path& volume) {
  const std::string name = volume.filename().string();
  benchmark::RegisterBenchmark(("io/read_tiff/" + name).c_str(),
                               [volume](benchmark::State& state) {
                                 for (auto _ : state)
                                   benchmark::DoNotOptimize(io::read_tiff_stack(volume).voxels.data());
                               })
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();

  benchmark::RegisterBenchmark(("io/load_and_normalize/" + name).c_str(),
                               [volume](benchmark::State& state) {
                                 io::VolumeOptions options;
                                 for (auto _ : state)
                                   benchmark::DoNotOptimize(io::load_volume(volume, options).volume.voxels.data());
                               })
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();

  benchmark::RegisterBenchmark(("io/build_sparse_grid/" + name).c_str(),
                               [volume](benchmark::State& state) {
                                 const io::LoadedVolume loaded = io::load_volume(volume, io::VolumeOptions{});
                                 const io::SparseGridOptions options;
                                 std::int64_t active = 0;
                                 for (auto _ : state) {
                                   const io::SparseGrid grid =
                                       io::build_sparse_grid(loaded.volume, loaded.frame.aspect(), options);
                                   active = grid.active_voxels();
                                 }
                                 state.counters["active_voxels"] = static_cast<double>(active);
                               })
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();

  benchmark::RegisterBenchmark(
      ("io/build_sparse_grid_with_background/" + name).c_str(),
      [volume](benchmark::State& state) {
        const io::LoadedVolume loaded = io::load_volume(volume, io::VolumeOptions{});
        io::SparseGridOptions options;
        options.background_fraction = 0.01;
        for (auto _ : state) {
          benchmark::DoNotOptimize(
              io::build_sparse_grid(loaded.volume, loaded.frame.aspect(), options).active_voxels());
        }
      })
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();
}

}  // namespace hisnegs::apps::bench
