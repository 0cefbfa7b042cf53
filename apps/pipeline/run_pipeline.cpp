// SPDX-License-Identifier: Apache-2.0
// run_pipeline: open the run folder, run or reuse each stage (the reuse and resume
// rules), write the report. What a stage reads and writes is declared by the stage.
#include "apps/pipeline/run_pipeline.hpp"

#include <algorithm>
#include <filesystem>
#include <iterator>
#include <string>
#include <string_view>
#include <vector>

#include "apps/pipeline/format.hpp"
#include "apps/pipeline/run_report.hpp"
#include "apps/pipeline/stack_reading.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/folder_lock.hpp"
#include "io/stack_file.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::ordered_json;

// What a run writes at the top of its folder: the first component of every output
// a stage declares (gt, gmf.ply, train, ...) and the run's own record files.
template <RunStage... Stages>
std::vector<std::string> run_written_names(StageList<Stages...>) {
  std::vector<std::string> names{"report.md", "run.json", "config.yaml"};
  (..., [&] {
    for (const char* output : Stages::kOutputs) names.push_back(fs::path(output).begin()->string());
  }());
  return names;
}

// A stack (or a file behind it) that is one of the run's own outputs, or inside a
// folder a stage writes (gt, train, eval), is refused before any stage runs: the
// stage before it would rewrite it (R/gt/train/mips.tif as the stack of R).
void refuse_stack_among_outputs(const RunRequest& request) {
  std::error_code ec;
  const fs::path dir = fs::weakly_canonical(request.dir, ec);
  if (ec) return;  // the folder's own checks report it
  const std::vector<std::string> written = run_written_names(PipelineStages{});
  for (const fs::path& file : io::stack_identity(request.volume).files) {
    const fs::path stack = fs::weakly_canonical(file, ec);
    if (ec) continue;
    const fs::path inside = stack.lexically_relative(dir);
    if (inside.empty() || *inside.begin() == "..") continue;
    const std::string first = inside.begin()->string();
    if (std::find(written.begin(), written.end(), first) != written.end()) {
      io::fail_input(file, "is a file of the run folder " + request.dir.string() + " that the run writes (" + first +
                               "); copy it out of the folder or use another -o");
    }
  }
}

// Everything is checked before the run folder is touched.
void check_request(const RunRequest& request, const AppConfig& config) {
  config.validate();
  if (io::is_zarr_stack(request.volume)) {  // a folder stack: the run folder must not be inside it
    if (io::stack_identity(request.volume).holds(request.dir)) {
      io::fail_input(request.dir, "lies inside the input stack " + request.volume.string() + "; use another -o");
    }
  } else {
    io::require_stack_path(request.volume);
  }
  if (request.orbit_frames < 1 || request.orbit_frames > 3600) {
    throw io::InputError("--orbit-frames: " + std::to_string(request.orbit_frames) + " is outside [1, 3600]");
  }
  refuse_stack_among_outputs(request);
  // The folders a stage starts over hold only what a run wrote (never an input):
  // refused now, before four stages of work, not when that stage comes.
  check_stage_folder(request.dir, TrainStage::kFolder, request.volume);
  check_stage_folder(request.dir, EvalStage::kFolder, request.volume);
  // A memory limit that cannot hold the smallest brick of the stages that read the
  // stack is refused now too (the fit checks its own plan when it starts).
  const io::StackHeader header = io::inspect_stack(request.volume, io::stack_read_options(config.volume));
  const std::array<int, 3> shape{header.nx, header.ny, header.nz};
  const Progress quiet;
  (void)ground_truth_core(shape, request.reading, quiet);
  const double voxels = static_cast<double>(header.nx) * header.ny * header.nz;
  (void)reading_core(shape, request.reading, sparse_grid_need(config.sparse_grid, voxels, false), "vdb", quiet);
  io::SparseGridOptions training = config.sparse_grid;  // training's 3D term samples the background too
  training.background_fraction = config.gmf.background_fraction;
  (void)reading_core(shape, request.reading, sparse_grid_need(training, voxels, true), "train", quiet);
}

// Creates DIR, reads DIR/run.json, writes DIR/config.yaml and records the volume.
RunState open_run_folder(const RunRequest& request, const AppConfig& config) {
  fs::create_directories(request.dir);
  RunState state(request.dir);
  const std::string effective = dump_app_config(config);
  io::write_file_atomic(request.dir / "config.yaml", effective.data(), effective.size());
  state.set_field("volume", io::printable(request.volume.string(), 500));
  return state;
}

// Runs each stage unless it can be reused, numbering them "[i/n]" in progress.
class StageRunner {
 public:
  StageRunner(const RunRequest& request, RunState& state, const Progress& progress, int stages)
      : request_(request), state_(state), progress_(progress), stages_(stages) {}

  template <RunStage S>
  void run(const AppConfig& config) {
    ++number_;
    const typename S::Config slice(config);  // all the stage is given of the configuration
    const std::string fingerprint = stage_fingerprint<S>(slice, request_, state_);
    if (reuse(S::kName, S::kTitle, fingerprint, outputs_of<S>())) return;
    const bool resume = resumable(S::kName, fingerprint, S::kResumeMarker);
    const double before = start(S::kName, S::kTitle, fingerprint, resume);
    io::Stopwatch watch;
    Json facts = S::run(request_, slice, resume, progress_);
    if (!facts.is_null()) state_.set_field(S::kName, std::move(facts));
    finish(S::kName, fingerprint, before + watch.elapsed(), output_identities(outputs_of<S>()));
  }

  [[nodiscard]] const std::vector<StageTiming>& timings() const { return timings_; }

 private:
  template <RunStage S>
  std::vector<fs::path> outputs_of() const {
    std::vector<fs::path> paths;
    paths.reserve(std::size(S::kOutputs));
    for (const char* output : S::kOutputs) paths.push_back(request_.dir / output);
    return paths;
  }

  // The identity (size, modification time, inode) of each output, by its name in DIR.
  Json output_identities(const std::vector<fs::path>& outputs) const {
    Json ids = Json::object();
    for (const fs::path& p : outputs) {
      ids[p.lexically_relative(request_.dir).string()] = fs::exists(p) ? file_content_identity(p) : "";
    }
    return ids;
  }

  // A stage that finished with this fingerprint and left the very outputs it
  // recorded (not files another process wrote since) is reused.
  bool reuse(const std::string& name, const std::string& title, const std::string& fingerprint,
             const std::vector<fs::path>& outputs) {
    const Json previous = state_.stage(name);
    if (request_.force || previous.value("fingerprint", "") != fingerprint || previous.value("state", "") != "done" ||
        !previous.contains("outputs") || !previous["outputs"].is_object()) {
      return false;
    }
    const Json& recorded = previous["outputs"];
    const Json current = output_identities(outputs);
    for (const auto& [name, identity] : current.items()) {  // key order does not matter
      if (identity.get<std::string>().empty() || !recorded.contains(name) || recorded[name] != identity) return false;
    }
    const double seconds = previous.value("seconds", 0.0);
    timings_.push_back({name, seconds, true});
    progress_.say("run: [%d/%d] %s: reused (done earlier in %s)", number_, stages_, title.c_str(),
                  format_seconds(seconds).c_str());
    return true;
  }

  // A stage started with this fingerprint that left its resume marker continues.
  bool resumable(const std::string& name, const std::string& fingerprint, std::string_view marker) const {
    const Json previous = state_.stage(name);
    return !request_.force && !marker.empty() && previous.value("fingerprint", "") == fingerprint &&
           previous.value("state", "") == "started" && fs::exists(request_.dir / marker);
  }

  // Records the stage as started; returns the wall time of earlier sessions it continues.
  double start(const std::string& name, const std::string& title, const std::string& fingerprint, bool resume) {
    progress_.say("run: [%d/%d] %s%s", number_, stages_, title.c_str(), resume ? " (resuming)" : "");
    const double before = resume ? state_.stage(name).value("seconds_before", 0.0) : 0.0;
    state_.set(name, Json{{"fingerprint", fingerprint}, {"state", "started"}, {"seconds_before", before}});
    return before;
  }

  void finish(const std::string& name, const std::string& fingerprint, double seconds, Json outputs) {
    state_.set(name, Json{{"fingerprint", fingerprint}, {"state", "done"}, {"seconds", seconds},
                          {"outputs", std::move(outputs)}});
    timings_.push_back({name, seconds, false});
  }

  const RunRequest& request_;
  RunState& state_;
  const Progress& progress_;
  const int stages_;
  int number_ = 0;
  std::vector<StageTiming> timings_;
};

template <RunStage... Stages>
void run_stages(StageList<Stages...>, StageRunner& runner, const AppConfig& config) {
  (runner.run<Stages>(config), ...);
}

}  // namespace

RunSummary run_pipeline(const RunRequest& asked, const AppConfig& config, const Progress& progress) {
  check_request(asked, config);
  RunRequest request = asked;  // the stages of one run share one streaming pass over the stack
  if (request.reading.statistics_cache.empty()) request.reading.statistics_cache = request.dir / "stack_statistics.json";
  io::Stopwatch total;
  const io::FolderLock lock(request.dir);  // one writer per run folder, for the whole run
  if (const int stale = io::remove_stale_temporaries(request.dir, true); stale > 0) {
    progress.say("run: removed %d temporary file(s) of an interrupted earlier run", stale);
  }
  RunState state = open_run_folder(request, config);
  StageRunner runner(request, state, progress, PipelineStages::kCount);
  run_stages(PipelineStages{}, runner, config);
  RunSummary summary{runner.timings(), total.elapsed()};
  write_run_report(request.dir, state.json(), summary, request.backend);
  progress.say("run: report %s (%s)", (request.dir / "report.md").c_str(), format_seconds(summary.seconds).c_str());
  return summary;
}

}  // namespace hisnegs::apps
