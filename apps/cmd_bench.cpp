// `hisnegs bench SUITE [--volume F] [--benchmark_* flags]`: Google Benchmark suites.
#include <benchmark/benchmark.h>

#include <cstdio>
#include <unistd.h>

#include <filesystem>

#include "apps/bench/benchmarks.hpp"
#include "apps/cli_support.hpp"
#include "apps/commands_detail.hpp"
#include "io/error.hpp"

namespace hisnegs::apps {

void add_bench_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("bench", "run benchmarks (Google Benchmark); extra --benchmark_* flags pass through");
  struct Args {
    std::string suite;
    std::string volume;
    std::vector<int> sizes{256};
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("SUITE", args->suite, "io | gt | gmf")->required();
  cmd->add_option("--sizes", args->sizes, "gt: image sizes (default 256)")->delimiter(',');
  cmd->add_option("--volume", args->volume, "TIFF stack to measure (default: a synthetic stack written to a temp folder)");
  cmd->allow_extras();
  cmd->callback([cmd, args, &global] {
    if (args->suite != "io" && args->suite != "gt" && args->suite != "gmf") {
      throw io::InputError("bench: unknown suite '" + args->suite + "'; expected io|gt|gmf");
    }
    std::filesystem::path volume = args->volume;
    std::filesystem::path temp;
    if (args->suite == "gmf") {
      bench::register_gmf_benchmarks();
    } else if (volume.empty()) {
      temp = std::filesystem::temp_directory_path() / ("hisnegs-bench-" + std::to_string(::getpid()));
      volume = temp / "synthetic.tif";
      write_synthetic_stack(volume, global.config().synth, true);
    } else {
      io::require_regular_file(volume);
    }
    if (args->suite == "io") {
      bench::register_io_benchmarks(volume);
    } else if (args->suite == "gt") {
      for (int size : args->sizes) {
        if (size < 8 || size > 16384) throw io::InputError("--sizes: " + std::to_string(size) + " is outside [8, 16384]");
        bench::register_gt_benchmarks(volume, size);
      }
    }
    std::vector<std::string> extra = cmd->remaining();
    std::vector<char*> argv;
    std::string program = "hisnegs bench";
    argv.push_back(program.data());
    for (auto& e : extra) argv.push_back(e.data());
    int argc = static_cast<int>(argv.size());
    benchmark::Initialize(&argc, argv.data());
    if (benchmark::ReportUnrecognizedArguments(argc, argv.data())) throw io::InputError("bench: unrecognized arguments");
    benchmark::RunSpecifiedBenchmarks();
    benchmark::Shutdown();
    if (!temp.empty()) std::filesystem::remove_all(temp);
  });
}

}  // namespace hisnegs::apps
