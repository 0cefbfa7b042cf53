// `hisnegs demo [-o DIR]`: `hisnegs run` on the bundled synthetic neuron with the
// built-in demo profile (configs/demo.yaml) on the CPU back end: ground truth,
// GMF fit, training, evaluation, orbit GIF and DIR/report.md in a few minutes.
#include <cstdio>

#include "apps/cli/cli_support.hpp"
#include "apps/cli/commands_detail.hpp"
#include "apps/pipeline/run_pipeline.hpp"
#include "io/atomic_file.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {

const char* const kDemoProfile = R"(# The profile of `hisnegs demo` (built into the program; this copy is checked against it by a test):
# the bundled synthetic neuron through the whole pipeline in a few minutes on a 2-core CPU.
# Overlaid on the defaults (configs/default.yaml). Compared with the defaults: a smaller
# Adam GMF fit (6000 Gaussians, 30 s), and a short training (24 epochs, beta warm-up over
# 8 epochs, density control at epochs 8 and 16) instead of the report's 2000 epochs.
gmf:
  optimizer: adam
  gaussians: 6000
  time_budget_s: 30
  rounds: 4

train:
  epochs: 24
  beta_warmup_epochs: 8
  densify_from: 8
  densify_every: 8
  densify_until: 17
  prune_every: 8
  save_every: 8
)";

void add_demo_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand(
      "demo", "the whole pipeline on the bundled synthetic neuron, CPU, a few minutes (default: out/demo)");
  struct Args {
    std::string out = "out/demo", backend = "cpu";
    bool force = false;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("-o,--output", args->out, "output folder")->capture_default_str();
  cmd->add_option("--backend", args->backend, "cpu | cuda | auto")->capture_default_str();
  cmd->add_flag("--force", args->force, "redo every stage, even those finished earlier");
  cmd->callback([args, &global] {
    // --config FILE replaces the demo profile (FILE overlays the defaults as usual).
    const AppConfig config = global.config_path.empty() ? load_app_config_text(kDemoProfile, "demo profile")
                                                        : global.config();
    const std::filesystem::path dir = args->out;
    io::Stopwatch watch;
    // The synthetic stack is deterministic: keep an identical existing file (and its
    // modification time), so a second demo reuses the finished stages.
    const auto tif = dir / "volume.tif", fresh = dir / ".volume.new.tif";
    const io::Volume synthetic = write_synthetic_stack(fresh, config.synth, true);
    const bool same = std::filesystem::exists(tif) && io::read_file(tif) == io::read_file(fresh);
    if (same) {
      std::filesystem::remove(fresh);
    } else {
      std::filesystem::rename(fresh, tif);
    }
    if (!global.quiet) {
      std::printf("demo: synthetic neuron %s: X=%d Y=%d Z=%d (%s)\n", tif.c_str(), synthetic.nx, synthetic.ny,
                  synthetic.nz, same ? "unchanged" : "written");
    }
    const splat::Backend backend = splat::resolve_backend(splat::parse_backend_request(args->backend));
    run_pipeline({tif, dir, backend, args->force}, config, global.quiet);
    if (!global.quiet) {
      std::printf("demo: done in %s; open %s\n", format_seconds(watch.elapsed()).c_str(),
                  (dir / "report.md").c_str());
    }
  });
}

}  // namespace hisnegs::apps
