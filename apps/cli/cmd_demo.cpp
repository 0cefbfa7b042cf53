// SPDX-License-Identifier: Apache-2.0
// `hisnegs demo [-o DIR]`: `hisnegs run` on the bundled synthetic neuron with the
// built-in demo profile (pipeline/demo.hpp) on the CPU back end, in a few minutes.
#include <cstdio>

#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/demo.hpp"
#include "apps/pipeline/format.hpp"
#include "apps/pipeline/run_pipeline.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {

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
    const AppConfig config =
        global.config_path.empty() ? load_app_config_text(kDemoProfile, "demo profile") : global.config();
    const std::filesystem::path dir = args->out;
    const Progress progress = global.progress();
    io::Stopwatch watch;
    const std::filesystem::path tif = write_demo_volume(dir, SyntheticConfig(config), progress);
    const splat::Backend backend = splat::resolve_backend(splat::parse_backend_request(args->backend));
    run_pipeline({tif, dir, backend, args->force}, config, progress);
    progress.say("demo: done in %s; open %s", format_seconds(watch.elapsed()).c_str(), (dir / "report.md").c_str());
  });
}

}  // namespace hisnegs::apps
