// `hisnegs run VOLUME -o DIR`: the whole pipeline in one folder: the normalized,
// aspect-corrected volume as a sparse grid, ground truth of the training and
// evaluation orbits, the GMF fit, soft-MIP training, evaluation, an orbit GIF and
// DIR/report.md. DIR/run.json records each finished stage with a fingerprint of
// its inputs (the volume file, the config sections it reads, the stages it builds
// on), so a second run reuses what is still valid and resumes an interrupted
// training; --force redoes everything.
#include <cstdio>
#include <filesystem>
#include <functional>
#include <nlohmann/json.hpp>

#include "apps/cli/cli_support.hpp"
#include "apps/cli/commands_detail.hpp"
#include "apps/pipeline/run_pipeline.hpp"
#include "gmf/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "io/config.hpp"
#include "io/error.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {
namespace {

namespace fs = std::filesystem;
using Json = nlohmann::ordered_json;

// 64-bit FNV-1a of `text` as 16 hex digits.
std::string hash_hex(const std::string& text) {
  std::uint64_t h = 1469598103934665603ull;
  for (unsigned char c : text) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return strf("%016llx", static_cast<unsigned long long>(h));
}

// The YAML text of the named config sections (what a stage reads).
std::string sections_text(AppConfig config, std::initializer_list<const char*> names) {
  io::ConfigWriter writer;
  config.for_each_section([&](const char* name, auto& options) {
    for (const char* n : names) {
      if (std::string_view(n) == name) {
        writer.begin_section(name);
        options.visit(writer);
      }
    }
  });
  return writer.str();
}

// Path, size and modification time: a changed or replaced volume file is a new input.
std::string file_identity(const fs::path& path) {
  const auto size = fs::file_size(path);
  const auto mtime = fs::last_write_time(path).time_since_epoch().count();
  return fs::absolute(path).lexically_normal().string() + "|" + std::to_string(size) + "|" + std::to_string(mtime);
}

// DIR/run.json: per stage its fingerprint, state (started | done), wall time and the
// generation (a counter over the folder's life) at which it finished.
class RunState {
 public:
  explicit RunState(fs::path dir) : path_(std::move(dir) / "run.json") {
    if (!fs::exists(path_)) return;
    try {
      state_ = Json::parse(io::read_file(path_));
    } catch (const Json::exception& e) {
      io::fail_input(path_, std::string("not a hisnegs run record (") + e.what() + "); remove it or use --force");
    }
    if (!state_.is_object() || !state_.contains("stages") || !state_["stages"].is_object()) {
      io::fail_input(path_, "not a hisnegs run record (no \"stages\"); remove it or use --force");
    }
  }
  [[nodiscard]] Json stage(const std::string& name) const {
    return state_.contains("stages") && state_["stages"].contains(name) ? state_["stages"][name] : Json::object();
  }
  [[nodiscard]] std::int64_t generation(const std::string& name) const {
    return stage(name).value("generation", std::int64_t{-1});
  }
  void set(const std::string& name, Json record) {
    if (record.value("state", "") == "done") {
      const std::int64_t g = state_.value("generation", std::int64_t{0}) + 1;
      state_["generation"] = g;
      record["generation"] = g;
    }
    state_["stages"][name] = std::move(record);
    save();
  }
  void set_field(const std::string& key, Json value) {
    state_[key] = std::move(value);
    save();
  }
  [[nodiscard]] const Json& json() const { return state_; }

 private:
  void save() const {
    const std::string text = state_.dump(2) + "\n";
    io::write_file_atomic(path_, text.data(), text.size());
  }
  fs::path path_;
  Json state_ = Json{{"hisnegs_run_version", 1}, {"generation", 0}, {"stages", Json::object()}};
};

struct RunArgs {
  std::string volume, out, backend = "auto";
  bool force = false;
  int orbit_frames = 72;
  double orbit_elevation = 30.0;
  VolumeOverrides overrides;
};

}  // namespace

RunSummary run_pipeline(const RunRequest& request, AppConfig config, bool quiet) {
  config.validate();
  io::require_regular_file(request.volume);
  if (request.orbit_frames < 1 || request.orbit_frames > 3600) {
    throw io::InputError("--orbit-frames: " + std::to_string(request.orbit_frames) + " is outside [1, 3600]");
  }
  const fs::path dir = request.dir;
  fs::create_directories(dir);
  RunState state(dir);
  const splat::Backend backend = request.backend;
  RunSummary summary;
  io::Stopwatch total;
  const std::string effective = dump_app_config(config);
  io::write_file_atomic(dir / "config.yaml", effective.data(), effective.size());
  state.set_field("volume", io::printable(request.volume.string(), 500));

  int number = 0;
  constexpr int kStages = 6;
  // Runs `work(resume)` unless the stage finished earlier with this fingerprint and
  // its outputs exist. A `resumable` stage that was started with this fingerprint
  // and left `resume_marker` behind continues instead of starting over.
  auto stage = [&](const std::string& name, const std::string& title, const std::string& inputs,
                   const std::vector<fs::path>& outputs, const std::function<void(bool)>& work,
                   const fs::path& resume_marker = {}) {
    ++number;
    const std::string fingerprint = hash_hex(name + "\n" + inputs);
    const Json previous = state.stage(name);
    const bool same = previous.value("fingerprint", "") == fingerprint;
    bool outputs_exist = true;
    for (const fs::path& p : outputs) outputs_exist = outputs_exist && fs::exists(p);
    if (!request.force && same && previous.value("state", "") == "done" && outputs_exist) {
      const double seconds = previous.value("seconds", 0.0);
      summary.stages.push_back({name, seconds, true});
      if (!quiet) {
        std::printf("run: [%d/%d] %s: reused (done earlier in %s)\n", number, kStages, title.c_str(),
                    format_seconds(seconds).c_str());
        std::fflush(stdout);
      }
      return;
    }
    const bool resume = !request.force && same && previous.value("state", "") == "started" &&
                        !resume_marker.empty() && fs::exists(resume_marker);
    if (!quiet) {
      std::printf("run: [%d/%d] %s%s\n", number, kStages, title.c_str(), resume ? " (resuming)" : "");
      std::fflush(stdout);
    }
    const double before = resume ? previous.value("seconds_before", 0.0) : 0.0;
    state.set(name, Json{{"fingerprint", fingerprint}, {"state", "started"}, {"seconds_before", before}});
    io::Stopwatch watch;
    work(resume);
    const double seconds = before + watch.elapsed();
    state.set(name, Json{{"fingerprint", fingerprint}, {"state", "done"}, {"seconds", seconds}});
    summary.stages.push_back({name, seconds, false});
  };
  auto upstream = [&](std::initializer_list<const char*> names) {
    std::string s;
    for (const char* n : names) s += std::string(n) + "@" + std::to_string(state.generation(n)) + "\n";
    return s;
  };

  // Loaded on first use: only stages that run need the volume in memory.
  std::optional<io::LoadedVolume> loaded;
  auto volume = [&]() -> const io::LoadedVolume& {
    if (!loaded) loaded = io::load_volume(request.volume, config.volume);
    return *loaded;
  };

  stage("volume", "volume: normalize, aspect-correct, sparse grid",
        file_identity(request.volume) + "\n" + sections_text(config, {"volume", "sparse_grid"}),
        {dir / "volume.vdb", dir / "volume.json"}, [&](bool) {
          const io::SparseGrid grid =
              write_sparse_grid(request.volume, config.volume, config.sparse_grid, dir / "volume.vdb", quiet);
          const io::SparseGridMeta& m = grid.meta();
          const Json info{{"source", io::printable(request.volume.string(), 500)},
                          {"shape_xyz", m.shape_xyz},
                          {"spacing_um", m.spacing_um},
                          {"aspect", {m.aspect.x(), m.aspect.y(), m.aspect.z()}},
                          {"normalization", m.normalization.describe()},
                          {"active_voxels", grid.active_voxels()},
                          {"file_bytes", file_bytes(request.volume.string())}};
          const std::string text = info.dump(2) + "\n";
          io::write_file_atomic(dir / "volume.json", text.data(), text.size());
        });

  stage("ground_truth", "ground truth: ray-marched MIPs of the training and evaluation orbits",
        upstream({"volume"}) + sections_text(config, {"camera", "raymarch"}),
        {dir / "gt" / "train" / "mips.tif", dir / "gt" / "eval" / "mips.tif"}, [&](bool) {
          write_ground_truth_set(dir / "gt" / "train", "train", splat::training_orbit(config.camera), volume(),
                                 request.volume.string(), config.raymarch, backend, quiet);
          write_ground_truth_set(dir / "gt" / "eval", "eval", splat::evaluation_orbit(config.camera), volume(),
                                 request.volume.string(), config.raymarch, backend, quiet);
        });

  stage("fit", "GMF fit (stage 1)", upstream({"volume"}) + sections_text(config, {"volume", "sparse_grid", "gmf"}),
        {dir / "gmf.ply", dir / "fit_log.csv"}, [&](bool) {
          const FitOutcome fit = fit_to_checkpoint(request.volume.string(), config, dir / "gmf.ply", dir / "fit_log.csv", quiet);
          state.set_field("fit", Json{{"gaussians", fit.gaussians}, {"psnr_3d", fit.psnr_3d}, {"stop", fit.stop_reason}});
        });

  const fs::path train = dir / "train";
  stage("train", "soft-MIP splatting training (stage 2)",
        upstream({"fit", "ground_truth"}) + sections_text(config, {"train", "splat"}), {train / "final.ply"},
        [&](bool resume) {
          if (!resume) fs::remove_all(train);  // a stale or different run: start over
          train_model({dir / "gmf.ply", dir / "gt" / "train", train, backend, resume}, config, quiet);
        },
        train / "checkpoints" / "latest");

  stage("eval", "evaluation on the held-out views", upstream({"train", "ground_truth"}) + sections_text(config, {"splat"}),
        {dir / "eval" / "metrics.json"}, [&](bool) {
          fs::remove_all(dir / "eval");
          evaluate_model(train / "final.ply", dir / "gt" / "eval", dir / "eval", config, backend, quiet);
        });

  stage("orbit", "orbit GIF",
        upstream({"train"}) + sections_text(config, {"splat", "camera"}) +
            strf("frames %d elevation %.17g\n", request.orbit_frames, request.orbit_elevation),
        {dir / "orbit.gif", dir / "orbit.json"}, [&](bool) {
          const gmf::Checkpoint model = gmf::load_checkpoint((train / "final.ply").string());
          auto renderer = splat::make_splat_renderer(backend);
          const std::vector<double> seconds =
              write_orbit_gif(dir / "orbit.gif", *renderer, splat::flat_params(model.mixture), config.camera,
                              splat::SplatSettings::from(config.splat), request.orbit_frames, request.orbit_elevation, 50);
          const Json info{{"frames", request.orbit_frames},
                          {"elevation_deg", request.orbit_elevation},
                          {"width", config.camera.width},
                          {"height", config.camera.height},
                          {"gaussians", model.mixture.size()},
                          {"backend", std::string(splat::to_string(backend))},
                          {"seconds_per_frame", seconds}};
          const std::string text = info.dump(2) + "\n";
          io::write_file_atomic(dir / "orbit.json", text.data(), text.size());
          if (!quiet) std::printf("run: orbit: %d frames -> %s\n", request.orbit_frames, (dir / "orbit.gif").c_str());
        });

  summary.seconds = total.elapsed();
  write_run_report(dir, state.json(), summary, backend);
  if (!quiet) {
    std::printf("run: report %s (%s)\n", (dir / "report.md").c_str(), format_seconds(summary.seconds).c_str());
    std::fflush(stdout);
  }
  return summary;
}

void add_run_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand(
      "run", "the whole pipeline: ground truth, GMF fit, training, evaluation, orbit GIF and report.md in one folder");
  auto args = std::make_shared<RunArgs>();
  cmd->add_option("VOLUME", args->volume, "TIFF stack")->required();
  cmd->add_option("-o,--output", args->out, "run folder (reused stages are skipped)")->required();
  cmd->add_option("--backend", args->backend, "auto | cpu | cuda");
  cmd->add_flag("--force", args->force, "redo every stage, even those finished earlier");
  cmd->add_option("--orbit-frames", args->orbit_frames, "frames of the 360 degree orbit GIF")->capture_default_str();
  cmd->add_option("--orbit-elevation", args->orbit_elevation, "orbit elevation in degrees")->capture_default_str();
  args->overrides.add_to(cmd);
  cmd->callback([args, &global] {
    AppConfig config = global.config();
    args->overrides.apply(config.volume);
    io::require_regular_file(args->volume);  // before the back-end notice: a bad path is the one line
    const splat::Backend backend = splat::resolve_backend(splat::parse_backend_request(args->backend));
    run_pipeline({args->volume, args->out, backend, args->force, args->orbit_frames, args->orbit_elevation}, config,
                 global.quiet);
  });
}

}  // namespace hisnegs::apps
