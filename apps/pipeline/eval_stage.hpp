// SPDX-License-Identifier: Apache-2.0
// The evaluation stage (config section splat): a model rendered at the views of a
// ground-truth set and measured per view (CONVENTIONS "Metrics").
#pragma once

#include <filesystem>
#include <optional>

#include "apps/pipeline/config_slice.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/run_stage.hpp"
#include "apps/pipeline/stage_folder.hpp"
#include "splat/lod.hpp"
#include "splat/backend.hpp"
#include "splat/metrics.hpp"

namespace hisnegs::apps {

using EvalConfig = ConfigSlice<&AppConfig::splat, &AppConfig::volume>;

// Renders `model` at the views of the ground-truth set `set` (cameras.json + mips.tif)
// and writes DIR/metrics.json, DIR/metrics.csv, DIR/compare/NNN.png; one "eval: ..." line.
// With `stack` (the model's own stack, read with the volume options) also the
// model's halos (apps/pipeline/halo_measure.hpp), "halos" in metrics.json. With
// `lod`, each view drawn from the model's hierarchy as `render --lod` draws it
// ("lod" in metrics.json: each view's Gaussian count).
struct EvalOutcome {
  int views = 0;
  splat::MetricSummary psnr, mae, ssim;  // of the configured mode (splat.mode)
  // Both modes, whatever is configured: the soft and hard MIPs' PSNR, and the hard
  // MIP's on the foreground pixels (splat::foreground_split).
  splat::MetricSummary soft_psnr, hard_psnr, hard_psnr_fg;
};
EvalOutcome evaluate_model(const std::filesystem::path& model, const std::filesystem::path& set,
                           const std::filesystem::path& dir, const EvalConfig& config, splat::Backend backend,
                           const Progress& progress, const std::filesystem::path& stack = {},
                           const std::optional<splat::LodOptions>& lod = std::nullopt);

// In a run folder: DIR/eval from DIR/train/final.ply on DIR/gt/eval (DIR/eval cleared first).
struct EvalStage {
  using Config = EvalConfig;
  static constexpr const char* kName = "eval";
  static constexpr const char* kTitle = "evaluation on the held-out views";
  static constexpr std::array<const char*, 2> kUpstream{"train", "ground_truth"};
  static constexpr std::array<const char*, 1> kOutputs{"eval/metrics.json"};
  static constexpr const char* kResumeMarker = "";
  static constexpr std::string_view kFiles[] = {"metrics.csv", "metrics.json", "compare/[0-9]*.png"};
  static constexpr StageFolder kFolder{"eval", kFiles};  // cleared before each evaluation
  static std::string request_inputs(const RunRequest&) { return {}; }
  static nlohmann::ordered_json run(const RunRequest& request, const Config& config, bool resume,
                                    const Progress& progress);
};

}  // namespace hisnegs::apps
