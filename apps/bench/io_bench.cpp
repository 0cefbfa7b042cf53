// SPDX-License-Identifier: Apache-2.0
// io benchmarks: stack read (TIFF or HDF5), region reads through a VolumeSource,
// read + normalize, sparse grid build, .vdb write.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <array>
#include <vector>

#include "apps/bench/benchmarks.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"
#include "io/hdf5_stack.hpp"
#include "io/zarr_stack.hpp"
#include "io/stack_file.hpp"
#include "io/tiff_stack.hpp"
#include "io/volume_source.hpp"

namespace hisnegs::apps::bench {

namespace {

// Reading the stack: whole, by regions, and (TIFF) its last pages.
void register_reading(const std::filesystem::path& volume, const std::string& name) {
  benchmark::RegisterBenchmark(("io/read_stack/" + name).c_str(),
                               [volume](benchmark::State& state) {
                                 std::size_t voxels = 0;
                                 for (auto _ : state) {
                                   const io::Volume v = io::read_stack(volume);
                                   voxels = v.size();
                                   benchmark::DoNotOptimize(v.voxels.data());
                                 }
                                 // Bytes of float32 delivered (MB/s comparable with the region reads).
                                 state.SetBytesProcessed(static_cast<std::int64_t>(state.iterations() * voxels * 4));
                               })
      ->Unit(benchmark::kMillisecond)
      ->UseRealTime();

  // Regions of edge 64 and 256 (clipped to the stack) at the stack's centre, read
  // through the file's VolumeSource: what a brick of a bricked fit costs.
  for (const int edge : {64, 256}) {
    benchmark::RegisterBenchmark(("io/read_region_" + std::to_string(edge) + "/" + name).c_str(),
                                 [volume, edge](benchmark::State& state) {
                                   const auto source = io::open_volume_source(volume);
                                   io::VoxelBox box;
                                   const std::array<int, 3> n{source->nx, source->ny, source->nz};
                                   for (int a = 0; a < 3; ++a) {
                                     const int e = std::min(edge, n[a]);
                                     box.lo[a] = (n[a] - e) / 2;
                                     box.hi[a] = box.lo[a] + e;
                                   }
                                   std::vector<float> out(box.voxels());
                                   for (auto _ : state) {
                                     source->read(box, out.data());
                                     benchmark::DoNotOptimize(out.data());
                                   }
                                   state.SetBytesProcessed(
                                       static_cast<std::int64_t>(state.iterations() * box.voxels() * 4));
                                   state.counters["voxels"] = static_cast<double>(box.voxels());
                                 })
        ->Unit(benchmark::kMillisecond)
        ->UseRealTime();
  }

  // TIFF only: a 64-voxel region at the end of the stack, its pages reached by walking
  // the directory chain from page 0 or through the page index the source keeps.
  if (!io::is_hdf5_stack(volume) && !io::is_zarr_stack(volume)) {
    for (const bool indexed : {false, true}) {
      benchmark::RegisterBenchmark(
          ("io/tiff_region_64_last_pages_" + std::string(indexed ? "indexed" : "walked") + "/" + name).c_str(),
          [volume, indexed](benchmark::State& state) {
            const io::StackHeader h = io::inspect_stack(volume);
            const std::array<int, 3> n{h.nx, h.ny, h.nz}, lo{0, 0, std::max(0, h.nz - 64)};
            const std::array<int, 3> hi{std::min(64, n[0]), std::min(64, n[1]), n[2]};
            const auto index = indexed ? io::index_tiff_pages(volume) : nullptr;
            std::vector<float> out(static_cast<std::size_t>(hi[0]) * hi[1] * (hi[2] - lo[2]));
            for (auto _ : state) {
              io::read_tiff_region(volume, {}, lo, hi, out.data(), index.get());
              benchmark::DoNotOptimize(out.data());
            }
            state.counters["pages"] = static_cast<double>(h.nz);
          })
          ->Unit(benchmark::kMillisecond)
          ->UseRealTime();
    }
  }
}

// From the stack in memory: loading with normalization, and the sparse grids.
void register_in_memory(const std::filesystem::path& volume, const std::string& name) {
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

}  // namespace

void register_io_benchmarks(const std::filesystem::path& volume) {
  const std::string name = volume.filename().string();
  register_reading(volume, name);
  register_in_memory(volume, name);
}

}  // namespace hisnegs::apps::bench
