// The one-command pipeline behind `hisnegs run` and `hisnegs demo`, and the
// Markdown report it writes from the files of a run folder.
#pragma once

#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "apps/pipeline/app_config.hpp"
#include "apps/pipeline/report_tables.hpp"
#include "splat/backend.hpp"

namespace hisnegs::apps {

struct RunRequest {
  std::filesystem::path volume;  // TIFF stack
  std::filesystem::path dir;     // run folder
  splat::Backend backend = splat::Backend::kCpu;
  bool force = false;            // redo stages finished earlier
  int orbit_frames = 72;         // report Table 10: 72 frames, 5 degree steps
  double orbit_elevation = 30.0;
};

struct StageTiming {
  std::string name;
  double seconds = 0;   // wall time of the stage when it ran (an earlier run's, if reused)
  bool reused = false;  // finished by an earlier invocation
};

struct RunSummary {
  std::vector<StageTiming> stages;
  double seconds = 0;  // wall time of this invocation
};

// Runs (or reuses) every stage in `request.dir` and writes DIR/report.md. Stages:
// volume (volume.vdb, volume.json), ground_truth (gt/train, gt/eval), fit (gmf.ply,
// fit_log.csv), train (train/), eval (eval/), orbit (orbit.gif, orbit.json);
// DIR/run.json records them, DIR/config.yaml holds the effective configuration.
RunSummary run_pipeline(const RunRequest& request, AppConfig config, bool quiet);

// The built-in profile of `hisnegs demo`: configs/demo.yaml verbatim (a test checks
// that they are equal), overlaid on the defaults.
extern const char* const kDemoProfile;

// DIR/report.md from the run folder's files: summary, stage timings, per-view
// metrics (report Table 8), training curve, Gaussian statistics (Table 3), memory
// and compression (Table 12), orbit frame times (Table 10).
void write_run_report(const std::filesystem::path& dir, const nlohmann::ordered_json& run_state,
                      const RunSummary& summary, splat::Backend backend);

}  // namespace hisnegs::apps
