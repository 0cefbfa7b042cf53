// SPDX-License-Identifier: Apache-2.0
// write_sparse_grid and the run folder's volume stage.
#include "apps/pipeline/volume_stage.hpp"

#include "apps/pipeline/format.hpp"
#include "apps/pipeline/report_tables.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {

io::SparseGrid write_sparse_grid(const std::filesystem::path& volume_path, const VolumeConfig& config,
                                 const std::filesystem::path& out, const Progress& progress,
                                 const StackReading& reading) {
  io::Stopwatch watch;
  io::SparseGrid grid = read_sparse_grid(volume_path, config.get<&AppConfig::volume>(),
                                         config.get<&AppConfig::sparse_grid>(), reading, "vdb", progress);
  const double t_build = watch.lap();
  io::write_vdb(out, grid);
  const double t_write = watch.lap();
  const io::SparseGridMeta& m = grid.meta();
  const double total = static_cast<double>(m.shape_xyz[0]) * m.shape_xyz[1] * m.shape_xyz[2];
  progress.say(
      "vdb: wrote %s: %lld active voxels (%.3f %% of %.2f M), %lld background samples, %lld leaves, %s "
      "in memory (dense float32: %s); read and build %s, write %s",
      out.c_str(), static_cast<long long>(grid.active_voxels()), 100.0 * grid.active_voxels() / total, total / 1e6,
      static_cast<long long>(grid.background_voxels()), static_cast<long long>(grid.leaf_count()),
      format_bytes(static_cast<double>(grid.memory_bytes())).c_str(), format_bytes(total * 4.0).c_str(),
      format_seconds(t_build).c_str(), format_seconds(t_write).c_str());
  return grid;
}

std::string VolumeStage::request_inputs(const RunRequest& request) { return file_identity(request.volume) + "\n"; }

nlohmann::ordered_json VolumeStage::run(const RunRequest& request, const Config& config, bool,
                                        const Progress& progress) {
  const std::filesystem::path& dir = request.dir;
  const io::SparseGrid grid = write_sparse_grid(request.volume, config, dir / "volume.vdb", progress, request.reading);
  const io::SparseGridMeta& m = grid.meta();
  const nlohmann::ordered_json info{{"source", io::printable(request.volume.string(), 500)},
                                    {"shape_xyz", m.shape_xyz},
                                    {"spacing_um", m.spacing_um},
                                    {"aspect", {m.aspect.x(), m.aspect.y(), m.aspect.z()}},
                                    {"normalization", m.normalization.describe()},
                                    {"active_voxels", grid.active_voxels()},
                                    {"file_bytes", file_bytes(request.volume.string())}};
  const std::string text = info.dump(2) + "\n";
  io::write_file_atomic(dir / "volume.json", text.data(), text.size());
  return nullptr;
}

}  // namespace hisnegs::apps
