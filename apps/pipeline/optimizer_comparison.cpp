// SPDX-License-Identifier: Apache-2.0
// write_optimizer_comparison: gmf::compare_optimizers and its report files.
#include "apps/pipeline/optimizer_comparison.hpp"

#include <cmath>
#include <cstdio>
#include <sstream>

#include "apps/pipeline/format.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "apps/pipeline/plot.hpp"
#include "io/png.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {
namespace {

void write_text_file(const std::filesystem::path& path, const std::string& text) {
  io::write_file_atomic(path, text.data(), text.size());
}

std::string results_csv(const gmf::Comparison& c) {
  std::ostringstream s;
  s.precision(10);
  s << "optimizer,seconds_to_target,final_loss,final_psnr_3d,iterations,seconds,gaussians,stop_reason,"
       "beta_continuation\n";
  for (const auto& run : c.runs) {
    s << run.name << ",";
    if (run.seconds_to_target >= 0) s << run.seconds_to_target;
    s << "," << run.final_loss << ",";
    if (run.failure.empty()) s << run.result.final_psnr_3d;  // empty: a failed run has no final model
    s << "," << run.iterations << "," << run.result.seconds << "," << run.gaussians << ",\"" << run.result.stop_reason
      << "\"," << (run.continuation ? 1 : 0) << "\n";
  }
  return s.str();
}

std::string curves_csv(const gmf::Comparison& c) {
  std::ostringstream s;
  s << "optimizer," << fit_log_csv_header() << "\n";
  for (const auto& run : c.runs) append_fit_log_csv(s, run.result.log, run.name);
  return s.str();
}

std::string summary_md(const gmf::Comparison& c, const std::string& volume, const gmf::CompareOptions& o,
                       const gmf::GmfOptions& gmf, int K, std::int64_t samples) {
  const bool softmax = gmf.aggregation == gmf::Aggregation::kSoftmax;
  const double beta_start = gmf.beta_start, beta_end = softmax ? gmf.beta_end : 0.0;
  std::ostringstream s;
  char line[512];
  s << "# Optimizer comparison\n\n";
  s << "Volume `" << io::printable(volume, 200) << "`: " << samples << " samples, K = " << K
    << " Gaussians from the same grid initialization, density control off, the same loss "
       "(½ Σ w² (f − V)²) for every optimizer. Budget "
    << o.time_budget_s << " s of wall time per optimizer (the 3D PSNR measured after each round is not counted).";
  if (softmax) {
    s << " The loss is the softmax mixture's at β " << beta_end
      << " for every run and every logged point; the runs whose β column reads a → b solve at the fit's β "
         "schedule on the way there (β continuation), the others at β "
      << beta_end << " from the start.";
  }
  s << "\n\n";
  const gmf::OptimizerRun* adam = nullptr;
  for (const auto& run : c.runs) {
    if (run.optimizer == gmf::Optimizer::kAdam) adam = &run;
  }
  if (adam != nullptr) {
    std::snprintf(line, sizeof line, "Target: the loss Adam reached after %d steps, %.6g", c.adam_steps_done,
                  c.target_loss);
    s << line;
    if (c.adam_steps_done < o.adam_steps)
      s << " (Adam ran out of time before the " << o.adam_steps << " steps asked for)";
    s << ".\n\n";
  } else {
    s << "Adam was not run, so there is no target loss; compare final losses.\n\n";
  }
  s << "| optimizer | β | time to target | vs Adam | final loss | final 3D PSNR (dB) | iterations | seconds | stop "
       "|\n";
  s << "|---|---|---:|---:|---:|---:|---:|---:|---|\n";
  for (const auto& run : c.runs) {
    std::string to_target = "not reached", ratio = "-";
    if (run.seconds_to_target >= 0) {
      std::snprintf(line, sizeof line, "%.1f s", run.seconds_to_target);
      to_target = line;
      if (adam != nullptr && adam->seconds_to_target > 0) {
        std::snprintf(line, sizeof line, "%.2f×", run.seconds_to_target / adam->seconds_to_target);
        ratio = line;
      }
    }
    std::string psnr = "-";  // a failed run has no final model to measure
    if (run.failure.empty()) {
      std::snprintf(line, sizeof line, "%.2f", run.result.final_psnr_3d);
      psnr = line;
    }
    // The β each run solved at: the schedule (continuation) or the final β from the start.
    std::string beta = "-";
    if (beta_end > 0) {
      std::snprintf(line, sizeof line, run.continuation ? "%g → %g" : "%g", run.continuation ? beta_start : beta_end,
                    beta_end);
      beta = line;
    }
    std::snprintf(line, sizeof line, "| %s | %s | %s | %s | %.6g | %s | %d | %.1f | %s |\n", run.name.c_str(),
                  beta.c_str(), to_target.c_str(), ratio.c_str(), run.final_loss, psnr.c_str(), run.iterations,
                  run.result.seconds, run.result.stop_reason.c_str());
    s << line;
  }
  s << "\n![loss against wall time](loss_vs_time.png)\n\nPer-iteration logs: `curves.csv`; this table: "
       "`results.csv`.\n";
  return s.str();
}

io::Image8 loss_plot(const gmf::Comparison& c) {
  std::vector<PlotSeries> series;
  for (std::size_t i = 0; i < c.runs.size(); ++i) {
    PlotSeries s;
    s.label = c.runs[i].name;
    s.rgb = plot_color(static_cast<int>(i));
    for (const auto& it : c.runs[i].result.log) {
      s.x.push_back(it.seconds);
      s.y.push_back(it.loss);
    }
    series.push_back(std::move(s));
  }
  if (c.target_loss > 0) {
    PlotSeries target;
    target.label = "Adam target";
    target.rgb = {128, 128, 128};
    double t_max = 0;
    for (const auto& run : c.runs) t_max = std::max(t_max, run.result.seconds);
    target.x = {0.0, t_max};
    target.y = {c.target_loss, c.target_loss};
    series.push_back(std::move(target));
  }
  PlotOptions o;
  o.title = "GMF loss against wall time (same init, same samples)";
  o.x_label = "seconds";
  o.y_label = "loss";
  o.log_y = true;
  return plot_lines(series, o);
}

}  // namespace

gmf::Comparison compare_prepared(const FitSetup& setup, const std::string& volume, const FitConfig& config,
                                 const gmf::CompareOptions& compare, const std::filesystem::path& dir,
                                 const Progress& progress) {
  io::Stopwatch watch;
  if (!dir.empty()) std::filesystem::create_directories(dir);
  const auto samples = static_cast<std::int64_t>(setup.samples.size());
  auto save = [&](const gmf::Comparison& c) {
    if (dir.empty()) return;
    write_text_file(dir / "results.csv", results_csv(c));
    write_text_file(dir / "curves.csv", curves_csv(c));
    write_text_file(dir / "summary.md", summary_md(c, volume, compare, config.get<&AppConfig::gmf>(),
                                                   static_cast<int>(setup.mixture.size()), samples));
    io::write_png(dir / "loss_vs_time.png", loss_plot(c));
  };
  gmf::Comparison c = gmf::compare_optimizers(
      setup.loaded.volume, setup.samples, setup.loaded.frame, setup.mixture, config.get<&AppConfig::gmf>(), compare,
      [&](const gmf::OptimizerRun& run, const gmf::FitIteration& it) {
        if (it.psnr_3d < 0 && it.iteration % 25 != 0) return;
        progress.say("compare: %-8s iteration %5d: loss %.6g%s, %s", run.name.c_str(), it.iteration, it.loss,
                     it.psnr_3d >= 0 ? (", 3D PSNR " + std::to_string(it.psnr_3d).substr(0, 5) + " dB").c_str() : "",
                     format_seconds(it.seconds).c_str());
      },
      save);
  for (const auto& run : c.runs) {
    progress.say("compare: %-8s final loss %.6g, 3D PSNR %.2f dB, %s to Adam's target", run.name.c_str(),
                 run.final_loss, run.result.final_psnr_3d,
                 run.seconds_to_target >= 0 ? format_seconds(run.seconds_to_target).c_str() : "never");
  }
  if (!dir.empty()) {
    progress.say("compare: wrote %s/{summary.md,results.csv,curves.csv,loss_vs_time.png} (%s)", dir.c_str(),
                 format_seconds(watch.elapsed()).c_str());
  }
  return c;
}

gmf::Comparison write_optimizer_comparison(const std::filesystem::path& dir, const std::string& volume,
                                           const FitConfig& config, const gmf::CompareOptions& compare,
                                           const Progress& progress) {
  const FitSetup setup = prepare_fit(volume, config, "compare", progress);
  return compare_prepared(setup, volume, config, compare, dir, progress);
}

}  // namespace hisnegs::apps
