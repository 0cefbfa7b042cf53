// `hisnegs vdb VOLUME -o out.vdb`: the sparse OpenVDB form of a stack (config
// sections `volume` and `sparse_grid`).
#include <cstdio>

#include "apps/cli/cli_support.hpp"
#include "apps/cli/commands_detail.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {

io::SparseGrid write_sparse_grid(const std::filesystem::path& volume_path, const io::VolumeOptions& volume,
                                 const io::SparseGridOptions& sparse, const std::filesystem::path& out, bool quiet) {
  sparse.validate();
  io::Stopwatch watch;
  const io::LoadedVolume loaded = io::load_volume(volume_path, volume);
  const double t_load = watch.lap();
  io::SparseGrid grid = io::build_sparse_grid(loaded.volume, loaded.frame.aspect(), sparse);
  const double t_build = watch.lap();
  io::write_vdb(out, grid);
  const double t_write = watch.lap();
  if (!quiet) {
    const double total = static_cast<double>(loaded.volume.size());
    std::printf("vdb: wrote %s: %lld active voxels (%.3f %% of %.2f M), %lld background samples, %lld leaves, %s "
                "in memory (dense float32: %s); load %s, build %s, write %s\n",
                out.c_str(), static_cast<long long>(grid.active_voxels()), 100.0 * grid.active_voxels() / total,
                total / 1e6, static_cast<long long>(grid.background_voxels()),
                static_cast<long long>(grid.leaf_count()), format_bytes(static_cast<double>(grid.memory_bytes())).c_str(),
                format_bytes(total * 4.0).c_str(), format_seconds(t_load).c_str(), format_seconds(t_build).c_str(),
                format_seconds(t_write).c_str());
  }
  return grid;
}

void add_vdb_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("vdb", "convert a TIFF stack to a sparse OpenVDB grid (foreground + band)");
  struct Args {
    std::string volume, out;
    std::optional<double> threshold, background_fraction;
    std::optional<int> band;
    std::optional<std::uint64_t> seed;
    VolumeOverrides overrides;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("VOLUME", args->volume, "TIFF stack")->required();
  cmd->add_option("-o,--output", args->out, "output .vdb path")->required();
  cmd->add_option("--threshold", args->threshold, "normalized foreground level (sparse_grid.threshold)");
  cmd->add_option("--band", args->band, "dilation in voxels (sparse_grid.band_voxels)");
  cmd->add_option("--background-fraction", args->background_fraction,
                  "share of the other voxels sampled into the `background` grid");
  cmd->add_option("--seed", args->seed, "background sampling seed");
  args->overrides.add_to(cmd);
  cmd->callback([args, &global] {
    io::VolumeOptions volume = global.config().volume;
    args->overrides.apply(volume);
    io::SparseGridOptions sparse = global.config().sparse_grid;
    if (args->threshold) sparse.threshold = *args->threshold;
    if (args->band) sparse.band_voxels = *args->band;
    if (args->background_fraction) sparse.background_fraction = *args->background_fraction;
    if (args->seed) sparse.seed = *args->seed;
    write_sparse_grid(args->volume, volume, sparse, args->out, global.quiet);
  });
}

}  // namespace hisnegs::apps
