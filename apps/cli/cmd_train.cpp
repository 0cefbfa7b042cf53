// `hisnegs train --init gmf.ply --data GTDIR -o RUNDIR`: stage-2 soft-MIP splatting
// training (config sections `train`, `splat`) on GTDIR/train: RUNDIR/log.csv,
// RUNDIR/checkpoints/, RUNDIR/final.ply, RUNDIR/training_curve.png; --resume continues.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <sstream>

#include "apps/cli/cli_support.hpp"
#include "apps/cli/commands_detail.hpp"
#include "gmf/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/plot.hpp"
#include "io/png.hpp"
#include "io/timer.hpp"
#include "splat/trainer.hpp"

namespace hisnegs::apps {
namespace {

struct TrainArgs {
  std::string init, data, out, backend = "auto";
  bool resume = false;
  std::optional<int> epochs;
};

struct LogRow {
  int epoch = 0;
  double seconds = 0, loss = 0, psnr = 0;
  int gaussians = 0;
  double beta = 0, lr = 0;
};

constexpr const char* kLogHeader = "epoch,seconds,loss,psnr,K,beta,lr";

std::string csv_of(const std::vector<LogRow>& rows) {
  std::string s = std::string(kLogHeader) + "\n";
  char line[256];
  for (const LogRow& r : rows) {
    std::snprintf(line, sizeof line, "%d,%.6f,%.10g,%.10g,%d,%.10g,%.10g\n", r.epoch, r.seconds, r.loss, r.psnr,
                  r.gaussians, r.beta, r.lr);
    s += line;
  }
  return s;
}

// The rows of an earlier log.csv up to epoch `last` (what a resumed run continues).
std::vector<LogRow> read_log(const std::filesystem::path& path, int last) {
  std::vector<LogRow> rows;
  std::ifstream in(path);
  if (!in) return rows;
  std::string line;
  std::getline(in, line);
  if (line != kLogHeader) io::fail_input(path, "not a training log (header \"" + io::printable(line, 80) + "\")");
  while (std::getline(in, line)) {
    LogRow r;
    if (std::sscanf(line.c_str(), "%d,%lf,%lf,%lf,%d,%lf,%lf", &r.epoch, &r.seconds, &r.loss, &r.psnr, &r.gaussians,
                    &r.beta, &r.lr) != 7) {
      io::fail_input(path, "malformed line \"" + io::printable(line, 80) + "\"");
    }
    if (r.epoch <= last) rows.push_back(r);
  }
  return rows;
}

// Loss (log scale) above PSNR, both against the epoch.
io::Image8 training_curve(const std::vector<LogRow>& rows) {
  io::PlotSeries loss{"loss (Eq. 16)", {}, {}, io::plot_color(0)};
  io::PlotSeries psnr{"PSNR (dB)", {}, {}, io::plot_color(1)};
  for (const LogRow& r : rows) {
    loss.x.push_back(r.epoch);
    loss.y.push_back(r.loss);
    psnr.x.push_back(r.epoch);
    psnr.y.push_back(r.psnr);
  }
  io::PlotOptions top;
  top.height = 400;
  top.title = "training loss";
  top.x_label = "epoch";
  top.y_label = "loss";
  top.log_y = true;
  io::PlotOptions bottom = top;
  bottom.title = "training PSNR (mean over views)";
  bottom.y_label = "dB";
  bottom.log_y = false;
  io::Image8 a = io::plot_lines(std::span(&loss, 1), top);
  const io::Image8 b = io::plot_lines(std::span(&psnr, 1), bottom);
  a.pixels.insert(a.pixels.end(), b.pixels.begin(), b.pixels.end());  // same width and channels: stack
  a.height += b.height;
  return a;
}

gmf::GaussianMixture mixture_of(std::span<const float> params) {
  gmf::GaussianMixture mixture;
  for (std::size_t k = 0; k * gmf::kGaussianParamCount < params.size(); ++k) {
    std::array<float, gmf::kGaussianParamCount> values;
    std::copy_n(params.begin() + static_cast<std::ptrdiff_t>(k * gmf::kGaussianParamCount), values.size(),
                values.begin());
    mixture.push_back(gmf::from_array(values));
  }
  return mixture;
}

}  // namespace

TrainOutcome train_model(const TrainRequest& request, const AppConfig& config, bool quiet) {
  config.train.validate();
  config.splat.validate();
  if (config.splat.mode != splat::MipMode::kSoft) {
    throw io::InputError("train: splat.mode must be soft (training differentiates the soft MIP)");
  }
  const std::filesystem::path run = request.run, checkpoints = run / "checkpoints";
  if (!request.resume && std::filesystem::exists(checkpoints / "latest")) {
    io::fail_input(run, "already holds a training run (checkpoints/latest); use --resume or another -o");
  }
  const splat::Backend backend = request.backend;
  splat::TrainingData data = splat::load_training_data(request.data);
  const gmf::Checkpoint init = gmf::load_checkpoint(request.init.string());
  const auto flat = splat::flat_params(init.mixture);
  // hisnegs worlds are [-a, a] with max a = 1; a model from elsewhere without aspect: 1.
  const double scene_scale =
      init.meta.aspect ? *std::max_element(init.meta.aspect->begin(), init.meta.aspect->end()) : 1.0;
  const int views = data.count(), width = data.intrinsics.width, height = data.intrinsics.height;
  splat::Trainer trainer(config.train, splat::SplatSettings::from(config.splat), std::move(data),
                         std::vector<float>(flat.begin(), flat.end()), splat::make_splat_renderer(backend),
                         scene_scale);
  gmf::CheckpointMeta meta = init.meta;
  std::erase_if(meta.extra, [](const auto& kv) { return kv.first == "init"; });
  meta.extra.emplace_back("init", io::printable(request.init.string(), 200));

  std::vector<LogRow> rows;
  if (request.resume) {
    io::remove_stale_temporaries(run);  // e.g. a log.csv write the crash interrupted
    const int epoch = splat::resume_training(checkpoints, trainer);
    rows = read_log(run / "log.csv", epoch);
  }
  if (!quiet) {
    std::printf("train: %d views of %dx%d, K %d, %d epochs%s, %s back end\n", views, width, height,
                trainer.gaussians(), config.train.epochs,
                request.resume ? (" (resuming after epoch " + std::to_string(trainer.epoch()) + ")").c_str() : "",
                std::string(splat::to_string(backend)).c_str());
    std::fflush(stdout);
  }
  const double seconds_before = rows.empty() ? 0.0 : rows.back().seconds;
  io::Stopwatch watch;
  const int first_epoch = trainer.epoch();
  while (!trainer.finished()) {
    const splat::EpochReport r = trainer.run_epoch();
    rows.push_back({r.epoch, seconds_before + watch.elapsed(), r.loss, r.psnr, r.gaussians, r.beta, r.lr});
    const std::string csv = csv_of(rows);
    io::write_file_atomic(run / "log.csv", csv.data(), csv.size());
    if (trainer.checkpoint_due()) splat::save_training_checkpoint(checkpoints, trainer, meta);
    if (!quiet) {
      const double per_epoch = watch.elapsed() / (trainer.epoch() - first_epoch);
      std::printf("train: epoch %d/%d: loss %.6g, PSNR %.2f dB, K %d, beta %.4g, lr %.3g, %s/epoch, ETA %s",
                  r.epoch, config.train.epochs, r.loss, r.psnr, r.gaussians, r.beta, r.lr,
                  format_seconds(r.seconds).c_str(),
                  format_seconds(per_epoch * (config.train.epochs - trainer.epoch())).c_str());
      if (r.split + r.cloned + r.pruned > 0) {
        std::printf(" (%d split, %d cloned, %d pruned)", r.split, r.cloned, r.pruned);
      }
      std::printf("\n");
      std::fflush(stdout);
    }
  }
  gmf::CheckpointMeta final_meta = meta;
  std::erase_if(final_meta.extra, [](const auto& kv) { return kv.first == "train_epoch"; });
  final_meta.extra.emplace_back("train_epoch", std::to_string(trainer.epoch()));
  gmf::save_checkpoint(run / "final.ply", mixture_of(trainer.params()), final_meta);
  io::write_png(run / "training_curve.png", training_curve(rows));
  if (!quiet) {
    std::printf("train: wrote %s: K %d, PSNR %.2f dB, %s\n", (run / "final.ply").c_str(), trainer.gaussians(),
                rows.empty() ? 0.0 : rows.back().psnr, format_seconds(watch.elapsed()).c_str());
  }
  return {trainer.epoch(), trainer.gaussians(), rows.empty() ? 0.0 : rows.back().psnr,
          rows.empty() ? 0.0 : rows.back().seconds};
}

void add_train_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("train", "train Gaussians on ground-truth MIPs by soft-MIP splatting (report §6)");
  auto args = std::make_shared<TrainArgs>();
  cmd->add_option("--init", args->init, "initial model (.ply, e.g. from `hisnegs fit`)")->required();
  cmd->add_option("--data", args->data, "ground-truth folder of `hisnegs gt` (uses GTDIR/train)")->required();
  cmd->add_option("-o,--output", args->out, "run folder (log.csv, checkpoints/, final.ply, training_curve.png)")
      ->required();
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  cmd->add_flag("--resume", args->resume, "continue from RUNDIR/checkpoints/latest");
  cmd->add_option("--epochs", args->epochs, "number of epochs (train.epochs)");
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    if (args->epochs) config.train.epochs = *args->epochs;
    train_model({args->init, std::filesystem::path(args->data) / "train", args->out,
                 splat::resolve_backend(splat::parse_backend_request(args->backend)), args->resume},
                config, global.quiet);
  });
}

}  // namespace hisnegs::apps
