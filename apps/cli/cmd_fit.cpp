// `hisnegs fit VOLUME -o model.ply`: the GMF stage (config sections `volume`,
// `sparse_grid`, `gmf`): init on the foreground grid, Ceres fit, checkpoint, CSV log.
#include <cstdio>
#include <sstream>

#include "apps/cli/cli_support.hpp"
#include "apps/cli/commands_detail.hpp"
#include "gmf/checkpoint.hpp"
#include "gmf/fit.hpp"
#include "gmf/init.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/load_volume.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {
namespace {

std::string csv_of(const std::vector<gmf::FitIteration>& log) {
  std::ostringstream s;
  s.precision(10);
  s << "iteration,seconds,loss,psnr_3d,gaussians,round\n";
  for (const auto& it : log) {
    s << it.iteration << "," << it.seconds << "," << it.loss << ",";
    if (it.psnr_3d >= 0) s << it.psnr_3d;
    s << "," << it.gaussians << "," << it.round << "\n";
  }
  return s.str();
}

}  // namespace

FitSetup prepare_fit(const std::string& volume_path, const AppConfig& config, const char* label, bool quiet) {
  io::Stopwatch watch;
  FitSetup setup;
  setup.loaded = io::load_volume(volume_path, config.volume);
  io::SparseGridOptions sparse = config.sparse_grid;
  sparse.background_fraction = config.gmf.background_fraction;  // the fit's own need (see GmfOptions)
  setup.grid = io::build_sparse_grid(setup.loaded.volume, setup.loaded.frame.aspect(), sparse);
  gmf::InitReport init_report;
  setup.mixture = gmf::initialize_on_grid(setup.loaded.volume, setup.loaded.frame, config.sparse_grid.threshold,
                                          config.gmf.gaussians, &init_report);
  if (!quiet) {
    std::printf("%s: %s: %lld samples (%lld active voxels), %zu Gaussians on a %.4g grid (budget %d), %s\n", label,
                volume_path.c_str(), static_cast<long long>(setup.grid.active_voxels() + setup.grid.background_voxels()),
                static_cast<long long>(setup.grid.active_voxels()), setup.mixture.size(), init_report.cell_world,
                config.gmf.gaussians, format_seconds(watch.elapsed()).c_str());
  }
  return setup;
}

gmf::CheckpointMeta checkpoint_meta(const io::LoadedVolume& loaded, const std::string& source) {
  gmf::CheckpointMeta meta;
  const io::Volume& v = loaded.volume;
  meta.volume_shape_zyx = std::array<int, 3>{v.nz, v.ny, v.nx};
  meta.spacing_um = v.spacing.um;
  const Eigen::Vector3d& a = loaded.frame.aspect();
  meta.aspect = std::array<double, 3>{a.x(), a.y(), a.z()};
  meta.normalization = v.normalization.describe();
  meta.extra.emplace_back("source", io::printable(source, 200));
  return meta;
}

FitOutcome fit_to_checkpoint(const std::string& volume, const AppConfig& config, const std::filesystem::path& out,
                             const std::filesystem::path& log_csv, bool quiet) {
  io::Stopwatch watch;
  FitSetup setup = prepare_fit(volume, config, "fit", quiet);
  gmf::GaussianMixture& mixture = setup.mixture;
  const gmf::FitResult result = gmf::fit_mixture(setup.loaded.volume, setup.grid, mixture, config.gmf, [&](const gmf::FitIteration& it) {
    if (quiet) return;
    if (it.psnr_3d >= 0) {
      std::printf("fit: round %d done: loss %.6g, 3D PSNR %.2f dB, K %d, %s\n", it.round, it.loss, it.psnr_3d,
                  it.gaussians, format_seconds(it.seconds).c_str());
    } else {
      std::printf("fit: round %d iteration %d: loss %.6g, K %d, %s\n", it.round, it.iteration, it.loss, it.gaussians,
                  format_seconds(it.seconds).c_str());
    }
    std::fflush(stdout);
  });
  if (!quiet) {
    for (const gmf::FitRound& r : result.rounds) {
      std::printf("fit: round %d density control: %d pruned, %d split, %d cloned -> K %d\n", r.round, r.pruned,
                  r.split, r.cloned, r.gaussians);
    }
  }
  const gmf::CheckpointMeta meta = checkpoint_meta(setup.loaded, volume);
  gmf::save_checkpoint(out, mixture, meta);
  if (!log_csv.empty()) {
    const std::string csv = csv_of(result.log);
    io::write_file_atomic(log_csv, csv.data(), csv.size());
  }
  const FitOutcome outcome{mixture.size(), result.final_psnr_3d, watch.elapsed(), result.stop_reason};
  if (!quiet) {
    std::printf("fit: wrote %s: K %zu (%d pruned), 3D PSNR %.2f dB, %s (%s)\n", out.c_str(), mixture.size(),
                result.pruned, result.final_psnr_3d, format_seconds(outcome.seconds).c_str(), result.stop_reason.c_str());
  }
  return outcome;
}

void add_fit_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("fit", "fit a Gaussian Mixture Field to a stack with Ceres (writes a .ply checkpoint)");
  struct Args {
    std::string volume, out, optimizer, log;
    std::optional<int> gaussians;
    std::optional<double> time_budget;
    VolumeOverrides overrides;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("VOLUME", args->volume, "TIFF stack")->required();
  cmd->add_option("-o,--output", args->out, "output checkpoint (.ply)")->required();
  cmd->add_option("--optimizer", args->optimizer, "lm | lm-cgnr | dogleg | lbfgs | adam (gmf.optimizer)");
  cmd->add_option("--gaussians", args->gaussians, "Gaussian budget (gmf.gaussians)");
  cmd->add_option("--time-budget", args->time_budget, "wall-clock limit in seconds (gmf.time_budget_s)");
  cmd->add_option("--log", args->log, "CSV of iteration, seconds, loss, 3D PSNR, K");
  args->overrides.add_to(cmd);
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    args->overrides.apply(config.volume);
    if (!args->optimizer.empty()) io::set_enum_field(config.gmf, "optimizer", args->optimizer, "--optimizer");
    if (args->gaussians) config.gmf.gaussians = *args->gaussians;
    if (args->time_budget) config.gmf.time_budget_s = *args->time_budget;
    config.gmf.validate();
    fit_to_checkpoint(args->volume, config, args->out, args->log, global.quiet);
  });
}

}  // namespace hisnegs::apps
