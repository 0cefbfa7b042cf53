// SPDX-License-Identifier: Apache-2.0
// `hisnegs bench SUITE [--volume F] [--benchmark_* flags]`: options of the Google
// Benchmark suites and of `bench report` (apps/bench/).
#include <benchmark/benchmark.h>

#include <unistd.h>
#include <cstdio>

#include <filesystem>

#include "apps/bench/bench_report.hpp"
#include "apps/bench/benchmarks.hpp"
#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/synthetic_stack.hpp"
#include "io/error.hpp"
#include "io/stack_file.hpp"
#include "splat/camera.hpp"

namespace hisnegs::apps {
namespace {

struct BenchArgs {
  std::string suite;
  std::string volume;
  std::vector<int> sizes;
  std::vector<int> gaussians{12000, 25000, 37000, 50000, 62000};
  std::vector<float> betas;
  std::string out, model, backend = "auto";
  bench::BenchReportRequest report;
  [[nodiscard]] bool is_report() const { return suite == "report"; }
};

void add_bench_options(CLI::App* cmd, BenchArgs& a) {
  cmd->add_option("SUITE", a.suite, "io | gt | gmf | render | report")->required();
  cmd->add_option("--sizes", a.sizes, "gt, render: image sizes (default gt 256, render 128,256,512,1024)")
      ->delimiter(',');
  cmd->add_option("--gaussians", a.gaussians, "render: K values at 256² (default 12000,...,62000)")->delimiter(',');
  cmd->add_option("--betas", a.betas,
                  "render, report: soft-MIP beta values (default render 1,10,50,100,500; report 1,5,...,500)")
      ->delimiter(',');
  cmd->add_option("-o,--output", a.out, "report: output folder (report.md, table7/9/10/11/12.csv)");
  cmd->add_option("--model", a.model,
                  "report: checkpoint to measure (default: synthetic K = 50000); gmf with --volume: the objective's "
                  "value and gradient at this model");
  cmd->add_option("--backend", a.backend, "report: auto | cpu | cuda");
  cmd->add_option("--orbit-frames", a.report.orbit_frames, "report: Table 10 orbit frames")->capture_default_str();
  cmd->add_option("--views", a.report.quality_views, "report: evaluation views for Table 11 images")
      ->capture_default_str();
  cmd->add_option("--min-frames", a.report.min_frames, "report: fewest frames per timed case")->capture_default_str();
  cmd->add_option("--max-frames", a.report.max_frames, "report: most frames per timed case")->capture_default_str();
  cmd->add_option("--seconds-per-case", a.report.seconds_per_case, "report: time budget per timed case")
      ->capture_default_str();
  cmd->add_option("--volume", a.volume, "stack (TIFF or HDF5) to measure (default: a synthetic stack written to a temp folder)");
  cmd->allow_extras();
}

// Checks the suite and the value lists and fills in the suite's defaults.
void check_bench_args(BenchArgs& a) {
  const bool report = a.is_report();
  if (a.suite != "io" && a.suite != "gt" && a.suite != "gmf" && a.suite != "render" && !report) {
    throw io::InputError("bench: unknown suite '" + a.suite + "'; expected io|gt|gmf|render|report");
  }
  if (report && a.out.empty()) throw io::InputError("bench report: give the output folder with -o DIR");
  // Checked before any table is measured (a 0 here used to fail after three tables).
  if (report) {
    const bench::BenchReportRequest& r = a.report;
    if (r.quality_views < 1) throw io::InputError("--views: " + std::to_string(r.quality_views) + " must be >= 1");
    if (r.orbit_frames < 1) {
      throw io::InputError("--orbit-frames: " + std::to_string(r.orbit_frames) + " must be >= 1");
    }
    if (r.min_frames < 1 || r.max_frames < r.min_frames) {
      throw io::InputError("--min-frames " + std::to_string(r.min_frames) + ", --max-frames " +
                           std::to_string(r.max_frames) + ": need 1 <= min <= max");
    }
    if (!(r.seconds_per_case > 0)) {
      throw io::InputError("--seconds-per-case: " + std::to_string(r.seconds_per_case) + " must be > 0");
    }
  }
  if (a.sizes.empty()) {
    a.sizes = a.suite == "render" || report ? std::vector<int>{128, 256, 512, 1024} : std::vector<int>{256};
  }
  if (a.betas.empty()) a.betas = report ? a.report.betas : std::vector<float>{1, 10, 50, 100, 500};
  for (int size : a.sizes) {
    if (size < 8 || size > splat::kMaxImageSide) {
      throw io::InputError("--sizes: " + std::to_string(size) + " is outside [8, " +
                           std::to_string(splat::kMaxImageSide) + "]");
    }
  }
  for (int K : a.gaussians) {
    if (K < 1 || K > 10000000) throw io::InputError("--gaussians: " + std::to_string(K) + " is outside [1, 10^7]");
  }
  for (float b : a.betas) {
    if (!(b > 0 && b <= 1e4)) throw io::InputError("--betas: " + std::to_string(b) + " is outside (0, 10^4]");
  }
}

void run_bench_report(BenchArgs& a, const std::filesystem::path& volume, bool synthetic, const GlobalOptions& global) {
  bench::BenchReportRequest& r = a.report;
  r.dir = a.out;
  r.volume = volume;
  if (synthetic) r.volume_label = "the synthetic neuron (hisnegs synth with the configured synth section)";
  r.model = a.model;
  if (!r.model.empty()) io::require_regular_file(r.model);
  r.backend = splat::resolve_backend(splat::parse_backend_request(a.backend));
  r.sizes = a.sizes;
  r.gaussians = a.gaussians;
  r.betas = a.betas;
  bench::write_bench_report(r, global.progress());
}

// Registers the suite's benchmarks and runs them with the pass-through flags.
void run_benchmark_suite(const BenchArgs& a, const std::filesystem::path& volume, std::vector<std::string> extra) {
  if (a.suite == "io") {
    bench::register_io_benchmarks(volume);
  } else if (a.suite == "gt") {
    for (int size : a.sizes) bench::register_gt_benchmarks(volume, size);
  } else if (a.suite == "render") {
    // The ray marcher at the same sizes in the same run, for the speed-up (Table 7).
    bench::register_render_benchmarks(a.sizes, a.gaussians, a.betas);
    for (int size : a.sizes) bench::register_gt_benchmarks(volume, size);
  }
  std::vector<char*> argv;
  std::string program = "hisnegs bench";
  argv.push_back(program.data());
  for (auto& e : extra) argv.push_back(e.data());
  int argc = static_cast<int>(argv.size());
  benchmark::Initialize(&argc, argv.data());
  if (benchmark::ReportUnrecognizedArguments(argc, argv.data())) throw io::InputError("bench: unrecognized arguments");
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
}

}  // namespace

void add_bench_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("bench", "run benchmarks (Google Benchmark); extra --benchmark_* flags pass through");
  auto args = std::make_shared<BenchArgs>();
  add_bench_options(cmd, *args);
  cmd->callback([cmd, args, &global] {
    check_bench_args(*args);
    std::filesystem::path volume = args->volume;
    std::filesystem::path temp;
    if (args->suite == "gmf") {
      bench::register_gmf_benchmarks();
      if (!volume.empty() && !args->model.empty()) {  // the whole objective at a model, as hisnegs.Objective
        const AppConfig& config = global.config();
        bench::register_objective_benchmark(volume, args->model, config.volume, config.sparse_grid, config.gmf);
      }
    } else if (volume.empty()) {
      temp = std::filesystem::temp_directory_path() / ("hisnegs-bench-" + std::to_string(::getpid()));
      volume = temp / "synthetic.tif";
      write_synthetic_stack(volume, SyntheticConfig(global.config()), Progress{});
    } else {
      io::require_stack_path(volume);
    }
    if (args->is_report()) {
      run_bench_report(*args, volume, !temp.empty(), global);
    } else {
      run_benchmark_suite(*args, volume, cmd->remaining());
    }
    if (!temp.empty()) std::filesystem::remove_all(temp);
  });
}

}  // namespace hisnegs::apps
