// `hisnegs bench SUITE [--volume F] [--benchmark_* flags]`: Google Benchmark suites.
#include <benchmark/benchmark.h>

#include <cstdio>
#include <unistd.h>

#include <filesystem>

#include "apps/bench/bench_report.hpp"
#include "apps/bench/benchmarks.hpp"
#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/synthetic_stack.hpp"
#include "io/error.hpp"
#include "splat/camera.hpp"

namespace hisnegs::apps {

void add_bench_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("bench", "run benchmarks (Google Benchmark); extra --benchmark_* flags pass through");
  struct Args {
    std::string suite;
    std::string volume;
    std::vector<int> sizes;
    std::vector<int> gaussians{12000, 25000, 37000, 50000, 62000};
    std::vector<float> betas;
    std::string out, model, backend = "auto";
    bench::BenchReportRequest report;
  };
  auto args = std::make_shared<Args>();
  cmd->add_option("SUITE", args->suite, "io | gt | gmf | render | report")->required();
  cmd->add_option("--sizes", args->sizes, "gt, render: image sizes (default gt 256, render 128,256,512,1024)")
      ->delimiter(',');
  cmd->add_option("--gaussians", args->gaussians, "render: K values at 256² (default 12000,...,62000)")->delimiter(',');
  cmd->add_option("--betas", args->betas,
                  "render, report: soft-MIP beta values (default render 1,10,50,100,500; report 1,5,...,500)")
      ->delimiter(',');
  cmd->add_option("-o,--output", args->out, "report: output folder (report.md, table7/9/10/11/12.csv)");
  cmd->add_option("--model", args->model, "report: checkpoint to measure (default: synthetic K = 50000)");
  cmd->add_option("--backend", args->backend, "report: auto | cpu | cuda");
  cmd->add_option("--orbit-frames", args->report.orbit_frames, "report: Table 10 orbit frames")->capture_default_str();
  cmd->add_option("--views", args->report.quality_views, "report: evaluation views for Table 11 images")
      ->capture_default_str();
  cmd->add_option("--min-frames", args->report.min_frames, "report: fewest frames per timed case")->capture_default_str();
  cmd->add_option("--max-frames", args->report.max_frames, "report: most frames per timed case")->capture_default_str();
  cmd->add_option("--seconds-per-case", args->report.seconds_per_case, "report: time budget per timed case")
      ->capture_default_str();
  cmd->add_option("--volume", args->volume, "TIFF stack to measure (default: a synthetic stack written to a temp folder)");
  cmd->allow_extras();
  cmd->callback([cmd, args, &global] {
    const bool report = args->suite == "report";
    if (args->suite != "io" && args->suite != "gt" && args->suite != "gmf" && args->suite != "render" && !report) {
      throw io::InputError("bench: unknown suite '" + args->suite + "'; expected io|gt|gmf|render|report");
    }
    if (report && args->out.empty()) throw io::InputError("bench report: give the output folder with -o DIR");
    if (args->sizes.empty()) {
      args->sizes = args->suite == "render" || report ? std::vector<int>{128, 256, 512, 1024} : std::vector<int>{256};
    }
    if (args->betas.empty()) {
      args->betas = report ? args->report.betas : std::vector<float>{1, 10, 50, 100, 500};
    }
    for (int size : args->sizes) {
      if (size < 8 || size > splat::kMaxImageSide) {
        throw io::InputError("--sizes: " + std::to_string(size) + " is outside [8, " +
                             std::to_string(splat::kMaxImageSide) + "]");
      }
    }
    for (int K : args->gaussians) {
      if (K < 1 || K > 10000000) throw io::InputError("--gaussians: " + std::to_string(K) + " is outside [1, 10^7]");
    }
    for (float b : args->betas) {
      if (!(b > 0 && b <= 1e4)) throw io::InputError("--betas: " + std::to_string(b) + " is outside (0, 10^4]");
    }
    std::filesystem::path volume = args->volume;
    std::filesystem::path temp;
    if (args->suite == "gmf") {
      bench::register_gmf_benchmarks();
    } else if (volume.empty()) {
      temp = std::filesystem::temp_directory_path() / ("hisnegs-bench-" + std::to_string(::getpid()));
      volume = temp / "synthetic.tif";
      write_synthetic_stack(volume, SyntheticConfig(global.config()), Progress{});
    } else {
      io::require_regular_file(volume);
    }
    if (report) {
      bench::BenchReportRequest& r = args->report;
      r.dir = args->out;
      r.volume = volume;
      if (!temp.empty()) r.volume_label = "the synthetic neuron (hisnegs synth with the configured synth section)";
      r.model = args->model;
      if (!r.model.empty()) io::require_regular_file(r.model);
      r.backend = splat::resolve_backend(splat::parse_backend_request(args->backend));
      r.sizes = args->sizes;
      r.gaussians = args->gaussians;
      r.betas = args->betas;
      bench::write_bench_report(r, global.progress());
      if (!temp.empty()) std::filesystem::remove_all(temp);
      return;
    }
    if (args->suite == "io") {
      bench::register_io_benchmarks(volume);
    } else if (args->suite == "gt") {
      for (int size : args->sizes) bench::register_gt_benchmarks(volume, size);
    } else if (args->suite == "render") {
      // The ray marcher at the same sizes in the same run, for the speed-up (Table 7).
      bench::register_render_benchmarks(args->sizes, args->gaussians, args->betas);
      for (int size : args->sizes) bench::register_gt_benchmarks(volume, size);
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
