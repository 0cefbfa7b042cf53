// SPDX-License-Identifier: Apache-2.0
// train_model (set up, run the epochs, finish) and the run folder's training stage.
#include "apps/pipeline/train_stage.hpp"

#include <algorithm>
#include <optional>
#include <string>
#include <utility>

#include "apps/pipeline/distributed.hpp"
#include "apps/pipeline/format.hpp"
#include "apps/pipeline/ground_truth_stage.hpp"
#include "apps/pipeline/stage_folder.hpp"
#include "apps/pipeline/training_log.hpp"
#include "apps/pipeline/training_volume.hpp"
#include "gmf/core/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/folder_lock.hpp"
#include "io/timer.hpp"
#include "splat/background_floor.hpp"
#include "splat/trainer.hpp"
#include "splat/training_checkpoint.hpp"

namespace hisnegs::apps {
namespace {

namespace fs = std::filesystem;

// The final.ply header entry that says the initial model was kept.
const std::pair<std::string, std::string> kKeptInit{"train_kept", "init"};

// The MPI ranks as the trainer's step group (splat::StepGroup, distributed.hpp).
class JobSteps final : public splat::StepGroup {
 public:
  explicit JobSteps(const Job& job) : job_(job) {}
  [[nodiscard]] int rank() const override { return job_.rank(); }
  [[nodiscard]] int size() const override { return job_.size(); }
  void sum(std::span<float> values) const override { job_.sum_all(values); }
  void sum(std::span<double> values) const override { job_.sum_all(values); }

 private:
  const Job& job_;
};

// A training run in progress: the trainer, the checkpoint metadata and the log so far.
struct TrainingSession {
  std::optional<splat::Trainer> trainer;
  gmf::CheckpointMeta meta;  // of the initial model, with "init" naming it
  std::vector<TrainingLogRow> rows;
  int views = 0, width = 0, height = 0;
  std::vector<float> init_params;  // the initial model (train.keep_better_init)
};

void check_training(const TrainRequest& request, const TrainConfig& config) {
  config.get<&AppConfig::train>().validate();
  config.get<&AppConfig::splat>().validate();
  if (config.get<&AppConfig::splat>().mode != splat::MipMode::kSoftmax) {
    throw io::InputError("train: splat.mode must be soft (training differentiates the soft MIP)");
  }
  if (!request.resume && fs::exists(request.run / "checkpoints" / "latest")) {
    io::fail_input(request.run, "already holds a training run (checkpoints/latest); use --resume or another -o");
  }
}

// The trainer on the initial model and the ground truth, moved on to the latest
// checkpoint when resuming.
TrainingSession start_training(const TrainRequest& request, const TrainConfig& config, const Progress& progress) {
  TrainingSession s;
  splat::TrainingData data = splat::load_training_data(request.data);
  const gmf::Checkpoint init = gmf::load_checkpoint(request.init.string());
  const auto flat = splat::flat_params(init.mixture);
  s.init_params.assign(flat.begin(), flat.end());
  s.views = data.count();
  s.width = data.intrinsics.width;
  s.height = data.intrinsics.height;
  s.trainer.emplace(make_trainer(init, request.init.string(), std::move(data), config, request.backend, progress));
  if (const Job& ranks = job(); ranks.distributed()) {
    s.trainer->share_steps(std::make_shared<JobSteps>(ranks));
    const int B = config.get<&AppConfig::train>().views_per_step;
    progress.say("train: %d MPI ranks share the %d view%s of each step (train.views_per_step)%s; rank 0 writes",
                 ranks.size(), B, B == 1 ? "" : "s",
                 B < ranks.size() ? ": fewer views than ranks, so some ranks wait; set views_per_step to a multiple "
                                    "of the ranks"
                                  : "");
  }
  if (!request.volume.empty()) {
    s.trainer->attach_volume(make_training_volume(request.volume, config.get<&AppConfig::volume>(),
                                                  config.get<&AppConfig::sparse_grid>(), config.get<&AppConfig::gmf>(),
                                                  init.meta, request.reading, progress));
  } else {
    progress.say("train: no volume given: training on the views alone (no 3D term, no empty-space pruning)");
  }
  s.meta = init.meta;
  std::erase_if(s.meta.extra, [](const auto& kv) { return kv.first == "init"; });
  s.meta.extra.emplace_back("init", io::printable(request.init.string(), 200));
  if (request.resume) {
    // e.g. a log.csv write the crash interrupted (rank 0's to remove: it writes there)
    if (job().root()) io::remove_stale_temporaries(request.run);
    const int epoch = splat::resume_training(request.run / "checkpoints", *s.trainer);
    s.rows = read_training_log(request.run / "log.csv", epoch);
  }
  return s;
}

}  // namespace

splat::Trainer make_trainer(const gmf::Checkpoint& init, const std::string& init_name, splat::TrainingData data,
                            const TrainConfig& config, splat::Backend backend, const Progress& progress) {
  const auto flat = splat::flat_params(init.mixture);
  // hisnegs worlds are [-a, a] with max a = 1; a model from elsewhere without aspect: 1.
  const double scene_scale =
      init.meta.aspect ? *std::max_element(init.meta.aspect->begin(), init.meta.aspect->end()) : 1.0;
  // The model's background floor under every training view, as the ground truth has it.
  const splat::BackgroundFloors floors =
      splat::floors_of(init.meta, init_name, config.get<&AppConfig::splat>().background);
  std::vector<std::vector<float>> view_floors;
  if (!floors.none()) {
    for (const splat::CameraView& view : data.views) view_floors.push_back(floors(data.intrinsics, view));
    progress.say("train: the views are rendered over the MIP floor of the background the model records "
                 "(splat.background: false trains the Gaussians alone)");
  }
  splat::Trainer trainer(config.get<&AppConfig::train>(), splat::SplatSettings::from(config.get<&AppConfig::splat>()),
                         std::move(data), std::vector<float>(flat.begin(), flat.end()),
                         splat::make_splat_renderer(backend), scene_scale);
  trainer.set_floors(std::move(view_floors));
  return trainer;
}

namespace {

// Epochs until the schedule ends; after each: log.csv, a checkpoint when due, a line.
void run_epochs(TrainingSession& s, const fs::path& run, int epochs, const Progress& progress) {
  splat::Trainer& trainer = *s.trainer;
  const double seconds_before = s.rows.empty() ? 0.0 : s.rows.back().seconds;
  io::Stopwatch watch;
  const int first_epoch = trainer.epoch();
  while (!trainer.finished()) {
    const splat::EpochReport r = trainer.run_epoch();
    s.rows.push_back({r.epoch, seconds_before + watch.elapsed(), r.loss, r.psnr, r.gaussians, r.beta, r.lr});
    if (job().root()) {  // the ranks hold the same model: one writes
      const std::string csv = training_log_csv(s.rows);
      io::write_file_atomic(run / "log.csv", csv.data(), csv.size());
      if (trainer.checkpoint_due()) splat::save_training_checkpoint(run / "checkpoints", trainer, s.meta);
    }
    if (progress.quiet()) continue;
    const double per_epoch = watch.elapsed() / (trainer.epoch() - first_epoch);
    std::string line =
        strf("train: epoch %d/%d: loss %.6g, PSNR %.2f dB, K %d, beta %.4g, lr %.3g, %s/epoch, ETA %s", r.epoch, epochs,
             r.loss, r.psnr, r.gaussians, r.beta, r.lr, format_seconds(r.seconds).c_str(),
             format_seconds(per_epoch * (epochs - trainer.epoch())).c_str());
    if (trainer.has_volume()) line += strf(", 3D term %.4g", r.loss_3d);
    if (r.split + r.cloned + r.pruned > 0) {
      line += strf(" (%d split, %d cloned, %d pruned", r.split, r.cloned, r.pruned);
      line += r.pruned_empty > 0 ? strf(", %d of them in empty space)", r.pruned_empty) : std::string(")");
    }
    progress.line(line);
  }
}

// Whether training made the training views worse than the initial model (both as
// the MIP training ended on: hard after a hard share, else soft at beta_end; whole
// images), said in one line either way.
bool training_made_it_worse(TrainingSession& s, const splat::TrainOptions& train, const Progress& progress) {
  const splat::MipMode mode = train.hard_share > 0 ? splat::MipMode::kMax : splat::MipMode::kSoftmax;
  const double before = s.trainer->evaluate(s.init_params, train.beta_end, mode).psnr;
  const double after = s.trainer->evaluate(s.trainer->params(), train.beta_end, mode).psnr;
  const bool worse = after < before;
  const std::string as = train.hard_share > 0 ? std::string("as hard MIPs") : strf("at beta %g", train.beta_end);
  progress.say("train: the %d training views %s: initial model %.2f dB, trained %.2f dB%s", s.views, as.c_str(),
               before, after,
               worse ? ": training made them worse, so final.ply is the initial model "
                       "(train.keep_better_init: false keeps the trained one)"
                     : "");
  return worse;
}

// RUN/final.ply (tagged with its epoch; the initial model when `initial`, tagged
// so) and RUN/training_curve.png.
void finish_training(const TrainingSession& s, const fs::path& run, bool initial) {
  gmf::CheckpointMeta final_meta = s.meta;
  std::erase_if(final_meta.extra,
                [](const auto& kv) { return kv.first == "train_epoch" || kv.first == kKeptInit.first; });
  final_meta.extra.emplace_back("train_epoch", std::to_string(s.trainer->epoch()));
  if (initial) final_meta.extra.push_back(kKeptInit);
  // Trained to the end on the hard MIP (train.hard_share): a max-mixture now.
  if (!initial && s.trainer->options().hard_share > 0) {
    final_meta.aggregation = gmf::Aggregation::kMax;
    final_meta.beta = 0;
  }
  gmf::save_checkpoint(run / "final.ply", gmf::mixture_from_flat(initial ? s.init_params : s.trainer->params()), final_meta);
  io::write_png(run / "training_curve.png", training_curve(s.rows));
}

}  // namespace

bool kept_initial_model(const gmf::CheckpointMeta& meta) {
  return std::ranges::find(meta.extra, kKeptInit) != meta.extra.end();
}

splat::TrainOptions cpu_train_schedule() {
  splat::TrainOptions t;
  t.epochs = 100;
  t.lr_initial = 3e-4;        // the report's 0.003 moved a converged fit's means by ~a voxel per step
  t.beta_start = t.beta_end;  // the fit is already a max-mixture: no warm-up from a blend
  t.beta_warmup_epochs = 0;
  t.densify_from = t.densify_until = 1'000'000'000;  // never: splits and clones cost op1 5 dB
  t.save_every = 25;
  return t;
}

void choose_train_schedule(AppConfig& config, splat::Backend backend, const Progress& progress) {
  AppConfig built_in = config;
  built_in.train = splat::TrainOptions{};
  const bool default_schedule = dump_app_config(config) == dump_app_config(built_in);
  if (backend == splat::Backend::kCpu && default_schedule) {
    config.train = cpu_train_schedule();
    progress.say(
        "train: CPU back end: the CPU schedule (%d epochs, as configs/train_cpu.yaml); the default "
        "%d-epoch schedule is for a GPU. Set any train.* field to choose your own.",
        config.train.epochs, splat::TrainOptions{}.epochs);
  } else {
    progress.say("train: %s back end: %s schedule, %d epochs", std::string(splat::to_string(backend)).c_str(),
                 default_schedule ? "the default (GPU)" : "the configured", config.train.epochs);
  }
}

TrainOutcome train_model(const TrainRequest& request, const TrainConfig& config, const Progress& progress) {
  check_training(request, config);
  TrainingSession s;
  open_on_every_rank(job(), [&] { s = start_training(request, config, progress); });
  // One training per folder, before anything is written there (by rank 0 alone on
  // several ranks; the others wait until it holds the folder).
  const Job& ranks = job();
  std::optional<OutputFolderLock> lock;  // and the run folder's, for a stage of one
  if (ranks.root()) {
    lock.emplace(request.run);
    check_training(request, config);  // again, now that no other process can start one here
  }
  ranks.barrier();
  const int epochs = config.get<&AppConfig::train>().epochs;
  const std::string label = ground_truth_set_label(request.data);
  progress.say("train: %d views of %dx%d from %s%s, K %d, %d epochs%s, %s back end", s.views, s.width, s.height,
               request.data.c_str(), label.empty() ? "" : (" (gt set '" + label + "')").c_str(),
               s.trainer->gaussians(), epochs,
               request.resume ? (" (resuming after epoch " + std::to_string(s.trainer->epoch()) + ")").c_str() : "",
               std::string(splat::to_string(request.backend)).c_str());
  io::Stopwatch watch;
  run_epochs(s, request.run, epochs, progress);
  const splat::TrainOptions& train = config.get<&AppConfig::train>();
  const bool kept_init = train.keep_better_init && training_made_it_worse(s, train, progress);
  if (ranks.root()) finish_training(s, request.run, kept_init);
  const double psnr = s.rows.empty() ? 0.0 : s.rows.back().psnr;
  const int K = kept_init ? static_cast<int>(s.init_params.size() / gmf::kGaussianParamCount) : s.trainer->gaussians();
  progress.say("train: wrote %s: K %d%s, last epoch's PSNR %.2f dB, %s", (request.run / "final.ply").c_str(), K,
               kept_init ? " (the initial model)" : "", psnr, format_seconds(watch.elapsed()).c_str());
  return {s.trainer->epoch(), K, psnr, s.rows.empty() ? 0.0 : s.rows.back().seconds, kept_init};
}

nlohmann::ordered_json TrainStage::run(const RunRequest& request, const Config& config, bool resume,
                                       const Progress& progress) {
  const fs::path train = request.dir / "train";
  if (!resume) clear_stage_folder(request.dir, kFolder, request.volume);  // a stale or different run: start over
  train_model({request.dir / "gmf.ply", request.dir / "gt" / "train", train, request.backend, resume, request.volume,
               request.reading},
              config, progress);
  return nullptr;
}

}  // namespace hisnegs::apps
