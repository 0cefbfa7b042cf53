// `hisnegs demo -o DIR`: the main job on the bundled default data. Today: the
// synthetic stack, its sparse grid and ground-truth MIPs of the training and
// evaluation orbits; later issues extend it to fitting, training and evaluation.
#include <cstdio>

#include "apps/cli_support.hpp"
#include "apps/commands_detail.hpp"
#include "io/timer.hpp"
#include "splat/camera.hpp"

namespace hisnegs::apps {

void add_demo_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("demo", "run the pipeline on the bundled synthetic neuron (default: out/demo)");
  auto out = std::make_shared<std::string>("out/demo");
  cmd->add_option("-o,--output", *out, "output folder");
  cmd->callback([out, &global] {
    const std::filesystem::path dir = *out;
    const AppConfig& config = global.config();
    io::Stopwatch watch;
    const auto tif = dir / "volume.tif";
    write_synthetic_stack(tif, config.synth, global.quiet);
    const io::SparseGrid grid = write_sparse_grid(tif, config.volume, config.sparse_grid, dir / "volume.vdb", global.quiet);
    const io::LoadedVolume loaded = io::load_volume(tif, config.volume);
    const splat::Backend backend = splat::resolve_backend(splat::BackendRequest::kAuto);
    write_ground_truth_set(dir / "gt" / "train", "train", splat::training_orbit(config.camera), loaded, tif.string(),
                           config.raymarch, backend, global.quiet);
    write_ground_truth_set(dir / "gt" / "eval", "eval", splat::evaluation_orbit(config.camera), loaded, tif.string(),
                           config.raymarch, backend, global.quiet);
    const auto& m = grid.meta();
    std::printf("demo: volume X=%d Y=%d Z=%d, aspect (%.4g, %.4g, %.4g), %s; outputs in %s (%s)\n", m.shape_xyz[0],
                m.shape_xyz[1], m.shape_xyz[2], m.aspect.x(), m.aspect.y(), m.aspect.z(),
                m.normalization.describe().c_str(), dir.c_str(), format_seconds(watch.elapsed()).c_str());
    std::printf("demo: GMF fitting, training and evaluation are not part of the demo yet (issues 4-7)\n");
  });
}

}  // namespace hisnegs::apps
