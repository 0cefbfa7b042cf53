// SPDX-License-Identifier: Apache-2.0
// The training stage (config sections train, splat): soft-MIP splatting of a GMF
// checkpoint on ground-truth MIPs, resumable from its latest checkpoint.
#pragma once

#include <filesystem>

#include "apps/pipeline/config_slice.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/run_stage.hpp"
#include "apps/pipeline/stack_reading.hpp"
#include "apps/pipeline/stage_folder.hpp"
#include "gmf/core/checkpoint.hpp"
#include "splat/backend.hpp"
#include "splat/trainer.hpp"
#include "splat/training_data.hpp"

namespace hisnegs::apps {

// train and splat; volume, sparse_grid and gmf say how the 3D term samples the stack.
using TrainConfig =
    ConfigSlice<&AppConfig::volume, &AppConfig::sparse_grid, &AppConfig::gmf, &AppConfig::train, &AppConfig::splat>;

struct TrainRequest {
  std::filesystem::path init;  // initial checkpoint (.ply)
  std::filesystem::path data;  // a ground-truth set (cameras.json + mips.tif), e.g. GTDIR/train
  std::filesystem::path run;
  splat::Backend backend = splat::Backend::kCpu;
  bool resume = false;
  // The stack the model was fitted to: enables the 3D term (train.lambda_3d) and
  // empty-space pruning. Empty: training sees the views only.
  std::filesystem::path volume;
  StackReading reading{};  // how `volume` is read: whole, or tile by tile when it does not fit
};
// The trainer of `init` on `data` as `train` sets it up (the scene scale from the
// model's aspect, the background floor it records under every view unless
// splat.background is false), with one line when a floor is drawn. What the
// training stage and the Python module's hisnegs.train start from.
splat::Trainer make_trainer(const gmf::Checkpoint& init, const std::string& init_name, splat::TrainingData data,
                            const TrainConfig& config, splat::Backend backend, const Progress& progress);

struct TrainOutcome {
  int epochs = 0;
  int gaussians = 0;
  double psnr = 0;     // mean training-view PSNR of the last epoch
  double seconds = 0;  // training wall time, earlier sessions of a resumed run included
  // final.ply is the initial model: training made the training views worse
  // (train.keep_better_init).
  bool kept_init = false;
};
// Whether a final.ply that train_model wrote is the initial model (its
// `train_kept init` header entry).
[[nodiscard]] bool kept_initial_model(const gmf::CheckpointMeta& meta);
// The CPU schedule (configs/train_cpu.yaml's train section): a short refinement of
// the stage-1 fit, 100 epochs at a tenth of the report's step, β at its end value
// from the start, no split or clone (docs/benchmarks.md, "Stage 2 after the
// sub-voxel fit"), where the default 2000-epoch (GPU) schedule takes hours.
[[nodiscard]] splat::TrainOptions cpu_train_schedule();

// The schedule a run on `backend` trains with: on the CPU back end, when the
// config's train section is the built-in one (nothing in it was set), the CPU
// schedule; otherwise the config's own. Says which in one line.
void choose_train_schedule(AppConfig& config, splat::Backend backend, const Progress& progress);

// Writes RUN/log.csv, RUN/checkpoints/, RUN/final.ply, RUN/training_curve.png; a line
// at the start, per epoch and at the end. Throws io::InputError for a RUN holding a
// run unless `resume`, and for splat.mode other than soft.
TrainOutcome train_model(const TrainRequest& request, const TrainConfig& config, const Progress& progress);

// In a run folder: DIR/train from DIR/gmf.ply on DIR/gt/train, with the run's volume. A training that was
// started with the same inputs and left a checkpoint resumes; otherwise DIR/train
// is cleared first: only the files a run writes there (kFolder), and the run refuses
// to start when anything else is there.
struct TrainStage {
  using Config = TrainConfig;
  static constexpr const char* kName = "train";
  static constexpr const char* kTitle = "soft-MIP splatting training (stage 2)";
  static constexpr std::array<const char*, 3> kUpstream{"volume", "fit", "ground_truth"};
  static constexpr std::array<const char*, 1> kOutputs{"train/final.ply"};
  static constexpr const char* kResumeMarker = "train/checkpoints/latest";
  static constexpr std::string_view kFiles[] = {"log.csv",
                                                "final.ply",
                                                "training_curve.png",
                                                "checkpoints/latest",
                                                "checkpoints/epoch_[0-9]*.ply",
                                                "checkpoints/state_[0-9]*.bin"};
  static constexpr StageFolder kFolder{"train", kFiles};
  static std::string request_inputs(const RunRequest&) { return {}; }
  static nlohmann::ordered_json run(const RunRequest& request, const Config& config, bool resume,
                                    const Progress& progress);
};

}  // namespace hisnegs::apps
