// SPDX-License-Identifier: Apache-2.0
// reading_core, the cached streaming statistics and the sparse grid of a stack that
// may not fit in memory.
#include "apps/pipeline/stack_reading.hpp"

#include <algorithm>
#include <nlohmann/json.hpp>

#include "apps/pipeline/format.hpp"
#include "apps/pipeline/run_state.hpp"
#include "gmf/bricked/memory_plan.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {

int reading_core(const std::array<int, 3>& shape, const StackReading& reading, const BrickNeed& need,
                 const std::string& what, const Progress& progress) {
  if (reading.brick_voxels > 0) return reading.brick_voxels;
  const double bytes = io::resolve_memory_limit(reading.max_memory, "--max-memory").bytes;
  const auto brick = [&](int core) {
    double v = 1;
    for (int a = 0; a < 3; ++a) v *= std::min(shape[a], std::min(core, shape[a]) + 2 * need.halo);
    return need.base_bytes + need.bytes_per_voxel * v;
  };
  const int longest = *std::max_element(shape.begin(), shape.end());
  if (brick(longest) <= bytes) return 0;
  const int core = gmf::largest_core(shape, need.smallest, bytes, brick);
  if (brick(core) > bytes) {
    throw io::InputError("--max-memory = " + reading.max_memory + ": too small for " + what + ": a brick of " +
                         std::to_string(core) + " voxels needs " + io::gib_text(brick(core)) +
                         "; allow at least that");
  }
  progress.say("%s: the stack needs %s in memory, more than %s: read in bricks of %d voxels", what.c_str(),
               io::gib_text(brick(longest)).c_str(), io::gib_text(bytes).c_str(), core);
  return core;
}

BrickNeed sparse_grid_need(const io::SparseGridOptions& sparse, double stack_voxels, bool background_taken) {
  BrickNeed need;  // a tile is read and normalized in place
  const bool background = sparse.background_fraction > 0;
  need.bytes_per_voxel = background ? 8.0 : 4.0;
  const double samples = stack_voxels * sparse.background_fraction;
  // An OpenVDB float leaf: 512 values, two masks, its origin and bookkeeping.
  constexpr double kLeafBytes = 512 * 4 + 2 * 64 + 64;
  need.base_bytes += background_taken ? samples * 40.0 : std::min(samples, stack_voxels / 512.0) * kLeafBytes;
  need.halo = sparse.band_voxels;
  return need;
}

namespace {

// What the statistics depend on: the file's content identity and the options that
// choose and normalize its values.
std::string statistics_key(const std::filesystem::path& volume, const io::VolumeOptions& o) {
  const nlohmann::json key{{"file", file_content_identity(volume)},
                           {"normalization", std::string(io::to_string(o.normalization.method))},
                           {"percentile_lo", o.normalization.percentile_lo},
                           {"percentile_hi", o.normalization.percentile_hi},
                           {"channel", o.channel},
                           {"dataset", o.dataset},
                           {"timepoint", o.timepoint},
                           {"level", o.level}};
  return key.dump();
}

}  // namespace

io::Normalization source_normalization(const io::VolumeSource& source, const io::VolumeOptions& options,
                                       const std::filesystem::path& volume, const StackReading& reading,
                                       const Progress& progress, const io::ScanShare& share) {
  const std::filesystem::path& cache = reading.statistics_cache;
  const std::string key = cache.empty() ? "" : statistics_key(volume, options);
  std::error_code ec;
  if (!cache.empty() && std::filesystem::is_regular_file(cache, ec)) {
    try {
      const nlohmann::json j = nlohmann::json::parse(io::read_file(cache));
      if (j.at("key").get<std::string>() == key) {
        io::Normalization n;
        n.method = options.normalization.method;
        n.raw_lo = j.at("raw_lo").get<double>();
        n.raw_hi = j.at("raw_hi").get<double>();
        n.clipped_voxels = j.at("clipped_voxels").get<std::int64_t>();
        return n;
      }
    } catch (const std::exception&) {
      // a damaged cache is a cache miss: the pass below rewrites it
    }
  }
  const io::Normalization n =
      io::normalization_from(io::scan_statistics(source, 64u << 20, share), options.normalization, volume.string());
  if (!cache.empty() && share.part == 0) {
    const nlohmann::json j{{"key", key},
                           {"raw_lo", n.raw_lo},
                           {"raw_hi", n.raw_hi},
                           {"clipped_voxels", n.clipped_voxels},
                           {"normalization", n.describe()}};
    const std::string text = j.dump(2) + "\n";
    try {  // a cache that cannot be written costs the next stage a pass, not this one its result
      io::write_file_atomic(cache, text.data(), text.size());
    } catch (const std::exception& e) {
      progress.say("%s: the statistics were not cached (%s); the next stage repeats the pass", volume.c_str(), e.what());
    }
  }
  return n;
}

io::SparseGrid read_sparse_grid(const std::filesystem::path& volume, const io::VolumeOptions& options,
                                const io::SparseGridOptions& sparse, const StackReading& reading,
                                const std::string& what, const Progress& progress,
                                const io::SparseGrid::LeafVisitor& take_background) {
  options.validate();
  sparse.validate();
  const auto source = io::open_volume_source(volume, io::stack_read_options(options));
  const double voxels = static_cast<double>(source->nx) * source->ny * source->nz;
  int tile = reading_core({source->nx, source->ny, source->nz}, reading,
                          sparse_grid_need(sparse, voxels, static_cast<bool>(take_background)), what, progress);
  if (tile == 0) {
    const io::LoadedVolume loaded = io::load_volume(volume, options);
    return io::build_sparse_grid(loaded.volume, loaded.frame.aspect(), sparse);
  }
  tile = std::max(8, tile / 8 * 8);  // whole leaves
  io::Stopwatch watch;
  const io::Normalization map = source_normalization(*source, options, volume, reading, progress);
  const io::WorldFrame frame =
      io::stack_frame(source->nx, source->ny, source->nz, source->spacing, options.aspect, volume);
  const double t_stats = watch.lap();
  io::SparseGrid grid = io::build_sparse_grid(*source, map, frame.aspect(), sparse, tile, [&](int done, int total) {
    if (progress.meter) progress.meter(strf("%s: sparse grid tile %d/%d", what.c_str(), done, total), done == total);
  }, take_background);
  progress.say("%s: sparse grid of %s by tiles of %d voxels: statistics (%s) %s, tiles %s", what.c_str(),
               volume.c_str(), tile, map.describe().c_str(), format_seconds(t_stats).c_str(),
               format_seconds(watch.lap()).c_str());
  return grid;
}

}  // namespace hisnegs::apps
