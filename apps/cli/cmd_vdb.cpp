// SPDX-License-Identifier: Apache-2.0
// `hisnegs vdb VOLUME -o out.vdb`: options of the volume stage (config sections
// `volume` and `sparse_grid`, pipeline/volume_stage.hpp).
#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/volume_stage.hpp"

namespace hisnegs::apps {

void add_vdb_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("vdb", "convert a TIFF stack to a sparse OpenVDB grid (foreground + band)");
  struct Args {
    std::string volume, out;
    std::optional<double> threshold, background_fraction;
    std::optional<int> band;
    std::optional<std::uint64_t> seed;
    StackReadingOverrides reading;
    VolumeOverrides overrides;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("VOLUME", args->volume, kStackHelp)->required();
  cmd->add_option("-o,--output", args->out, "output .vdb path")->required();
  cmd->add_option("--threshold", args->threshold, "normalized foreground level (sparse_grid.threshold)");
  cmd->add_option("--band", args->band, "dilation in voxels (sparse_grid.band_voxels)");
  cmd->add_option("--background-fraction", args->background_fraction,
                  "share of the other voxels sampled into the `background` grid");
  cmd->add_option("--seed", args->seed, "background sampling seed");
  args->reading.add_to(cmd, "read");
  args->overrides.add_to(cmd);
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    args->overrides.apply(config.volume);
    io::SparseGridOptions& sparse = config.sparse_grid;
    if (args->threshold) sparse.threshold = *args->threshold;
    if (args->band) sparse.band_voxels = *args->band;
    if (args->background_fraction) sparse.background_fraction = *args->background_fraction;
    if (args->seed) sparse.seed = *args->seed;
    write_sparse_grid(args->volume, VolumeConfig(config), args->out, global.progress(), args->reading.reading(config));
  });
}

}  // namespace hisnegs::apps
