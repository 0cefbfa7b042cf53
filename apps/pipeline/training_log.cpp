// SPDX-License-Identifier: Apache-2.0
// RUN/log.csv of a training run (written, read back on resume) and its curve plot.
#include "apps/pipeline/training_log.hpp"

#include <cstdio>
#include <fstream>

#include "io/error.hpp"
#include "apps/pipeline/plot.hpp"

namespace hisnegs::apps {
namespace {

constexpr const char* kLogHeader = "epoch,seconds,loss,psnr,K,beta,lr";

}  // namespace

std::string training_log_csv(const std::vector<TrainingLogRow>& rows) {
  std::string s = std::string(kLogHeader) + "\n";
  char line[256];
  for (const TrainingLogRow& r : rows) {
    std::snprintf(line, sizeof line, "%d,%.6f,%.10g,%.10g,%d,%.10g,%.10g\n", r.epoch, r.seconds, r.loss, r.psnr,
                  r.gaussians, r.beta, r.lr);
    s += line;
  }
  return s;
}

std::vector<TrainingLogRow> read_training_log(const std::filesystem::path& path, int last) {
  std::vector<TrainingLogRow> rows;
  std::ifstream in(path);
  if (!in) return rows;
  std::string line;
  std::getline(in, line);
  if (line != kLogHeader) io::fail_input(path, "not a training log (header \"" + io::printable(line, 80) + "\")");
  while (std::getline(in, line)) {
    TrainingLogRow r;
    if (std::sscanf(line.c_str(), "%d,%lf,%lf,%lf,%d,%lf,%lf", &r.epoch, &r.seconds, &r.loss, &r.psnr, &r.gaussians,
                    &r.beta, &r.lr) != 7) {
      io::fail_input(path, "malformed line \"" + io::printable(line, 80) + "\"");
    }
    if (r.epoch <= last) rows.push_back(r);
  }
  return rows;
}

io::Image8 training_curve(const std::vector<TrainingLogRow>& rows) {
  PlotSeries loss{"loss (Eq. 16)", {}, {}, plot_color(0)};
  PlotSeries psnr{"PSNR (dB)", {}, {}, plot_color(1)};
  for (const TrainingLogRow& r : rows) {
    loss.x.push_back(r.epoch);
    loss.y.push_back(r.loss);
    psnr.x.push_back(r.epoch);
    psnr.y.push_back(r.psnr);
  }
  PlotOptions top;
  top.height = 400;
  top.title = "training loss";
  top.x_label = "epoch";
  top.y_label = "loss";
  top.log_y = true;
  PlotOptions bottom = top;
  bottom.title = "training PSNR (mean over views)";
  bottom.y_label = "dB";
  bottom.log_y = false;
  io::Image8 a = plot_lines(std::span(&loss, 1), top);
  const io::Image8 b = plot_lines(std::span(&psnr, 1), bottom);
  a.pixels.insert(a.pixels.end(), b.pixels.begin(), b.pixels.end());  // same width and channels: stack
  a.height += b.height;
  return a;
}

}  // namespace hisnegs::apps
