// SPDX-License-Identifier: Apache-2.0
// The one-command pipeline behind `hisnegs run` and `hisnegs demo`: its stages in
// order, and run_pipeline, which runs or reuses each in a run folder.
#pragma once

#include <string>
#include <vector>

#include "apps/pipeline/app_config.hpp"
#include "apps/pipeline/eval_stage.hpp"
#include "apps/pipeline/fit_stage.hpp"
#include "apps/pipeline/ground_truth_stage.hpp"
#include "apps/pipeline/run_summary.hpp"
#include "apps/pipeline/orbit_stage.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/run_stage.hpp"
#include "apps/pipeline/train_stage.hpp"
#include "apps/pipeline/volume_stage.hpp"

namespace hisnegs::apps {

// A list of stage types (what run_pipeline runs, in order; tests iterate over it).
template <RunStage... Stages>
struct StageList {
  static constexpr int kCount = sizeof...(Stages);
};
using PipelineStages = StageList<VolumeStage, GroundTruthStage, FitStage, TrainStage, EvalStage, OrbitStage>;


// Runs (or reuses) every stage of PipelineStages in `request.dir` and writes
// DIR/report.md; DIR/run.json records the stages, DIR/config.yaml holds the
// effective configuration. A stage is reused when it finished earlier with the same
// fingerprint (stage_fingerprint) and its outputs exist, unless `request.force`; a
// started stage with a resume marker continues. Progress: "run: [i/n] ..." per stage
// and the stages' own lines. Throws io::InputError for a bad request or run.json.
RunSummary run_pipeline(const RunRequest& request, const AppConfig& config, const Progress& progress);

}  // namespace hisnegs::apps
