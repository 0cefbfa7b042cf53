// SPDX-License-Identifier: Apache-2.0
// prepare_fit, fit_to_checkpoint (in memory, or the driver of the bricked fit of
// gmf/bricked/: the stack opened on every rank, the fingerprint of stack, config and
// plan, the brick folder locked, gmf::fit_bricked on this process's job with its
// signal handlers as the ranks' runtime, then rank 0's checkpoint, log and
// background), checkpoint_meta and the run folder's fit stage.
#include "apps/pipeline/fit_stage.hpp"

#include <algorithm>
#include <optional>
#include <sstream>

#include "apps/pipeline/app_config.hpp"
#include "apps/pipeline/distributed.hpp"
#include "apps/pipeline/format.hpp"
#include "apps/pipeline/interrupts.hpp"
#include "apps/pipeline/run_state.hpp"
#include "apps/pipeline/stage_folder.hpp"
#include "gmf/bricked/bricked_fit.hpp"
#include "gmf/bricked/memory_plan.hpp"
#include "gmf/fit.hpp"
#include "gmf/init.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"
#include "io/stack_file.hpp"
#include "io/timer.hpp"
#include "io/volume_source.hpp"
#include "splat/background_floor.hpp"

namespace hisnegs::apps {
namespace {

void report_iteration(const gmf::FitIteration& it, const Progress& progress) {
  if (it.psnr_3d >= 0) {
    progress.say("fit: final model: 3D PSNR %.2f dB over all voxels, %.2f dB over the foreground, K %d", it.psnr_3d,
                 it.psnr_fg, it.gaussians);
  } else if (it.psnr_fg >= 0) {
    progress.say("fit: round %d done: loss %.6g, foreground PSNR %.2f dB, K %d, beta %g, %s", it.round, it.loss,
                 it.psnr_fg, it.gaussians, it.beta, format_seconds(it.seconds).c_str());
  } else {
    progress.say("fit: round %d iteration %d: loss %.6g, K %d, %s", it.round, it.iteration, it.loss, it.gaussians,
                 format_seconds(it.seconds).c_str());
  }
}

}  // namespace

gmf::BackgroundField stack_background(const io::LoadedVolume& loaded, const FitConfig& config,
                                     const Progress& progress) {
  const gmf::BackgroundOptions& options = config.get<&AppConfig::background>();
  if (!options.estimate) {
    progress.say("fit: background: not estimated (background.estimate: false): renders draw no floor");
    return {};
  }
  gmf::BackgroundField field = gmf::estimate_background_field(loaded.volume, options);
  if (field.none()) {
    progress.say("fit: background: exactly 0 outside the neuron (%lld voxels): no floor to draw",
                 static_cast<long long>(field.merged.voxels));
  }
  return field;
}

namespace {

// "; 16 regions (4 x 4 x 1), each its own floor, 5 subtracted (floor 0), 2 on the
// whole stack's (under 4096 background voxels), p99 0.02 to 0.09", or "" for one region.
std::string regions_text(const gmf::BackgroundField& field) {
  if (!field.regional()) return "";
  const gmf::BackgroundField::Summary s = field.summary();
  const auto& c = field.regions.cells;
  std::string text = strf("; %d regions (%d x %d x %d), each its own floor", field.regions.count(), c[0], c[1], c[2]);
  if (s.subtracted > 0) text += strf(", %d subtracted (floor 0)", s.subtracted);
  if (s.merged > 0)
    text += strf(", %d on the whole stack's (under %lld background voxels)", s.merged,
                 static_cast<long long>(gmf::BackgroundField::kMinVoxels));
  if (s.p99_hi > 0.0) text += strf(", p99 %.4g to %.4g", s.p99_lo, s.p99_hi);
  return text;
}

}  // namespace

void record_background(const io::WorldFrame& frame, const FitConfig& config, gmf::BackgroundField field,
                       gmf::CheckpointMeta& meta, const Progress& progress) {
  io::Stopwatch watch;
  const double mean = field.merged.mean(), p99 = field.merged.quantile(0.99);
  const long long voxels = field.merged.voxels;
  const std::string regions = regions_text(field);
  const splat::FloorCalibration c = splat::calibrate_background(field, frame, config.get<&AppConfig::raymarch>());
  gmf::set_background(meta, field);
  progress.say(
      "fit: background: %lld voxels, mean %.4g, p99 %.4g%s; a ray gathers %.2f samples per voxel (fits the ray "
      "marcher's MIP of noise to %.1f %% on %d rays); renders draw its MIP floor, %s",
      voxels, mean, p99, regions.c_str(), c.samples_per_voxel, 100.0 * c.worst_relative_error, c.rays,
      format_seconds(watch.elapsed()).c_str());
}

std::string fit_log_csv_header() { return "iteration,seconds,loss,psnr_fg,psnr_3d,gaussians,round,beta"; }

void append_fit_log_csv(std::ostringstream& s, std::span<const gmf::FitIteration> log, const std::string& prefix) {
  s.precision(10);
  for (const auto& it : log) {
    if (!prefix.empty()) s << prefix << ",";
    s << it.iteration << "," << it.seconds << "," << it.loss << ",";
    if (it.psnr_fg >= 0) s << it.psnr_fg;
    s << ",";
    if (it.psnr_3d >= 0) s << it.psnr_3d;
    s << "," << it.gaussians << "," << it.round << "," << it.beta << "\n";
  }
}

FitStart FitStart::load(const std::filesystem::path& path, const io::WorldFrame& frame) {
  return of(gmf::load_checkpoint(path), frame, path);  // a regular file only, as every checkpoint
}

FitStart FitStart::of(gmf::Checkpoint model, const io::WorldFrame& frame, const std::filesystem::path& name) {
  const Eigen::Vector3d& a = frame.aspect();
  if (model.meta.aspect) {
    const std::array<double, 3>& m = *model.meta.aspect;
    for (int i = 0; i < 3; ++i) {
      if (std::abs(m[static_cast<std::size_t>(i)] - a[i]) > 0.02 * a[i]) {
        io::fail_input(name.string(), strf("is a model of the world box a = (%.4g, %.4g, %.4g), the stack's is (%.4g, "
                                           "%.4g, %.4g): not a fit of this stack (or of another --spacing/--aspect)",
                                           m[0], m[1], m[2], a.x(), a.y(), a.z()));
      }
    }
  }
  FitStart start;
  start.path = name;
  const std::span<const float> p = gmf::flat_params(model.mixture);
  start.identity = hash_hex(std::string(reinterpret_cast<const char*>(p.data()), p.size_bytes()));
  start.model = std::move(model.mixture);
  return start;
}

FitSetup prepare_fit(const std::string& volume_path, const FitConfig& config, const char* label,
                     const Progress& progress) {
  return prepare_fit(io::load_volume(volume_path, config.get<&AppConfig::volume>()), volume_path, config, label,
                     progress);
}

FitSetup prepare_fit(io::LoadedVolume loaded, const std::string& name, const FitConfig& config, const char* label,
                     const Progress& progress, const FitStart& start) {
  const gmf::GmfOptions& gmf = config.get<&AppConfig::gmf>();
  const io::SparseGridOptions& sparse_grid = config.get<&AppConfig::sparse_grid>();
  io::Stopwatch watch;
  FitSetup setup;
  setup.loaded = std::move(loaded);
  io::SparseGridOptions sparse = sparse_grid;
  sparse.background_fraction = gmf.background_fraction;  // the fit's own need (see GmfOptions)
  {
    const io::SparseGrid grid = io::build_sparse_grid(setup.loaded.volume, setup.loaded.frame.aspect(), sparse);
    setup.samples = gmf::fit_samples(grid, gmf);
    setup.active_voxels = grid.active_voxels();
  }
  if (!start.empty()) {
    setup.mixture = gmf::warm_start_mixture(start.model, setup.loaded.frame, gmf);
    if (setup.mixture.empty()) io::fail_input(start.path.string(), "has no Gaussian inside the stack's box");
    progress.say("%s: %s: %lld samples (%lld active voxels), %zu Gaussians from %s (of its %zu; budget %d), %s", label,
                 name.c_str(), static_cast<long long>(setup.samples.size()),
                 static_cast<long long>(setup.active_voxels), setup.mixture.size(), start.path.c_str(),
                 start.model.size(), gmf.gaussians, format_seconds(watch.elapsed()).c_str());
    return setup;
  }
  gmf::InitReport init_report;
  setup.mixture =
      gmf::initialize_mixture(setup.loaded.volume, setup.loaded.frame, sparse_grid.threshold, gmf, &init_report);
  progress.say("%s: %s: %lld samples (%lld active voxels), %zu Gaussians %s %.4g (budget %d), %s", label, name.c_str(),
               static_cast<long long>(setup.samples.size()), static_cast<long long>(setup.active_voxels),
               setup.mixture.size(), gmf.init == gmf::FitInit::kGrid ? "on a grid of step" : "at local maxima, spacing",
               init_report.cell_world, gmf.gaussians, format_seconds(watch.elapsed()).c_str());
  return setup;
}

gmf::CheckpointMeta checkpoint_meta(const io::WorldFrame& frame, const io::VoxelSpacing& spacing,
                                    const io::Normalization& normalization, const std::string& source) {
  gmf::CheckpointMeta meta;
  const Eigen::Vector3i& n = frame.shape();
  meta.volume_shape_zyx = std::array<int, 3>{n.z(), n.y(), n.x()};
  meta.spacing_um = spacing.um;
  const Eigen::Vector3d& a = frame.aspect();
  meta.aspect = std::array<double, 3>{a.x(), a.y(), a.z()};
  meta.normalization = normalization.describe();
  meta.extra.emplace_back("source", io::printable(source, 200));
  return meta;
}

gmf::CheckpointMeta checkpoint_meta(const io::LoadedVolume& loaded, const std::string& source) {
  return checkpoint_meta(loaded.frame, loaded.volume.spacing, loaded.volume.normalization, source);
}

namespace {

// The fingerprint of what decides the bricks: the stack (path, and the identity of
// every file behind it), its shape, the fit's config sections and the plan.
std::string fingerprint_of(const std::string& path, const io::VolumeSource& source, const FitConfig& config,
                           const gmf::BrickPlan& plan, const FitStart& start) {
  AppConfig slice;
  slice.volume = config.get<&AppConfig::volume>();
  slice.background = config.get<&AppConfig::background>();
  slice.sparse_grid = config.get<&AppConfig::sparse_grid>();
  slice.gmf = config.get<&AppConfig::gmf>();
  std::ostringstream s;
  s << std::filesystem::absolute(path).lexically_normal().string() << "\n";
  s << source.identity.content() << "\n";  // a BigDataViewer .xml: its .h5 too
  s << source.nx << " " << source.ny << " " << source.nz << "\n" << plan.describe() << "\n" << dump_app_config(slice);
  if (!start.empty()) s << "init " << start.identity << "\n";
  return hash_hex(s.str());
}

// What the fit of the stack opened as `source` is told, and the opening lines.
gmf::BrickedFitSetup open_stream(const std::string& volume, const FitConfig& config,
                                 const gmf::FitPlanChoice& choice, const io::VolumeSource* source,
                                 const FitStart& start, const Progress& progress) {
  const io::VolumeOptions& vo = config.get<&AppConfig::volume>();
  gmf::BrickedFitSetup s;
  s.path = volume;
  s.gmf = config.get<&AppConfig::gmf>();
  s.sparse = config.get<&AppConfig::sparse_grid>();
  s.background = config.get<&AppConfig::background>();
  s.normalization_options = vo.normalization;
  s.source = source;
  s.frame = io::stack_frame(source->nx, source->ny, source->nz, source->spacing, vo.aspect, volume);
  s.gmf.max_scale_world = gmf::brick_max_scale(s.frame, s.gmf);
  s.plan = choice.plan;
  s.regions = gmf::BackgroundRegions::of({source->nx, source->ny, source->nz}, s.background.region_voxels);
  s.max_memory = choice.max_memory;
  if (!start.empty()) {
    s.start = &start.model;
    s.gmf.beta_start = s.gmf.beta_end;  // the model was annealed already
  }
  progress.say("fit: %s: %d x %d x %d %s (%s as float32), %s; in-memory fit would need %s of %s: bricked: %s",
               volume.c_str(), source->nx, source->ny, source->nz,
               std::string(io::to_string(source->stored_as)).c_str(),
               io::gib_text(4.0 * static_cast<double>(source->whole().voxels())).c_str(), source->format.c_str(),
               io::gib_text(choice.whole_need).c_str(), choice.memory_source.c_str(), s.plan.describe().c_str());
  if (!start.empty()) {
    progress.say("fit: each brick starts from the Gaussians of %s centred in it (%zu in all; beta %g from the start)",
                 start.path.c_str(), start.model.size(), s.gmf.beta_end);
  }
  if (choice.for_ranks) {
    progress.say(
        "fit: %d MPI ranks: bricks of core %d voxels, two or more per rank (the same fit as "
        "--brick-voxels %d in one process)",
        job().size(), s.plan.core[0], s.plan.core[0]);
  }
  progress.say(
      "fit: each brick keeps the Gaussians centred in its core; scales <= %g voxels (gmf.stream_scale_voxels) "
      "reach at most sqrt(%g) x that, inside the halo; planned peak %s",
      s.gmf.stream_scale_voxels, s.gmf.mahalanobis_cutoff, io::gib_text(choice.brick_need).c_str());
  return s;
}

// The ranks' runtime: this process's signal handlers (apps/pipeline/interrupts.hpp).
gmf::RankRuntime signal_runtime() {
  gmf::RankRuntime r;
  r.note_on_stop = [](std::string_view line, const std::filesystem::path& marker) {
    set_interrupt_note(line, marker);
  };
  r.watch = [](const std::vector<std::pair<std::filesystem::path, std::filesystem::path>>& files, int wait_ms) {
    set_interrupt_watch(files, wait_ms);
  };
  return r;
}

// Rank 0's outputs: the checkpoint (brick after brick) with the fit's metadata and
// background, the log, and the brick folder removed.
void write_outputs(const gmf::BrickedFitSetup& s, const gmf::BrickStore& store, const gmf::BrickedFitResult& fit,
                   const FitConfig& config, const std::filesystem::path& out, const std::filesystem::path& log_csv,
                   const Progress& progress) {
  gmf::CheckpointMeta meta = checkpoint_meta(s.frame, s.source->spacing, fit.normalization, s.path);
  meta.extra.emplace_back("bricks", s.plan.describe());
  meta.aggregation = s.gmf.final_aggregation();
  meta.beta = fit.beta;
  const bool counted = std::any_of(fit.background.begin(), fit.background.end(),
                                   [](const gmf::BackgroundCounts& b) { return b.total > 0; });
  if (s.background.estimate && counted) {
    const gmf::BackgroundField field = gmf::background_field(fit.background, s.regions, s.background, s.path);
    if (field.none()) {
      progress.say("fit: background: exactly 0 outside the neuron (%lld voxels): no floor to draw",
                   static_cast<long long>(field.merged.voxels));
    } else {
      record_background(s.frame, config, field, meta, progress);
    }
  }
  store.write_checkpoint(fit.state.count, fit.state.kind, out, meta);
  if (!log_csv.empty()) {
    std::ostringstream csv;
    csv << fit_log_csv_header() << "\n";
    for (const gmf::BrickRecord& r : fit.records) append_fit_log_csv(csv, r.log, "");
    const std::string text = csv.str();
    io::write_file_atomic(log_csv, text.data(), text.size());
  }
  std::error_code ec;
  std::filesystem::remove_all(store.folder(), ec);  // the checkpoint holds everything now
}

FitOutcome run_streamed(const std::string& volume, const io::VolumeSource& source, const FitConfig& config,
                        const gmf::FitPlanChoice& choice, const FitStart& start, const std::filesystem::path& out,
                        const std::filesystem::path& log_csv, const Progress& progress) {
  io::Stopwatch watch;
  const gmf::BrickedFitSetup setup = open_stream(volume, config, choice, &source, start, progress);
  const gmf::BrickStore store(gmf::brick_folder(out), fingerprint_of(volume, source, config, setup.plan, start),
                              setup.frame, setup.regions.count());
  const Job& ranks = job();
  // Rank 0 (the only one alone) holds the folder.
  std::optional<OutputFolderLock> lock;  // and the run folder's, for a run's fit
  if (ranks.root()) lock.emplace(store.folder());
  ranks.barrier();
  const gmf::BrickedFitResult fit = gmf::fit_bricked(setup, store, ranks, signal_runtime(), progress);
  const std::size_t n = setup.plan.bricks.size();
  if (!ranks.root()) {  // rank 0 goes on alone: the checkpoint
    return FitOutcome{0, 0.0, watch.elapsed(), rank_prefix(ranks) + std::to_string(fit.fitted_here) + " bricks"};
  }
  write_outputs(setup, store, fit, config, out, log_csv, progress);
  const std::size_t total = fit.gaussians();
  FitOutcome outcome{total, fit.psnr_3d, watch.elapsed(),
                     std::string("bricks: ") + std::to_string(n) + (fit.seam ? " + seam pass" : "")};
  progress.say("fit: wrote %s: K %zu from %zu bricks, 3D PSNR %.2f dB (measured in %s), %s (fit %s)", out.c_str(),
               total, n, fit.psnr_3d, format_seconds(fit.measure_seconds).c_str(),
               format_seconds(outcome.seconds).c_str(), format_seconds(fit.fit_seconds).c_str());
  return outcome;
}

// The bricked fit of `volume` (opened as `source` on every rank) to the checkpoint
// `out` (and the log `log_csv` unless empty), with `choice` from
// gmf::choose_fit_plan (bricked). Same lines, checkpoint metadata and outcome as
// the in-memory fit.
FitOutcome fit_streamed(const std::string& volume, const io::VolumeSource& source, const FitConfig& config,
                        const gmf::FitPlanChoice& choice, const FitStart& start, const std::filesystem::path& out,
                        const std::filesystem::path& log_csv, const Progress& progress) {
  const std::filesystem::path folder = gmf::brick_folder(out);
  const bool created = !std::filesystem::exists(folder);
  try {
    return run_streamed(volume, source, config, choice, start, out, log_csv, progress);
  } catch (...) {
    if (!job().root()) throw;  // rank 0 made the folder: only it may remove it
    // A fit that fails before any brick finished leaves no folder it made (a killed
    // one cannot clean up; its folder is resumed or refused next time).
    std::error_code ec;
    bool finished = false;
    for (const auto& e : std::filesystem::directory_iterator(folder, ec)) {
      finished = finished || (e.path().extension() == ".json" && e.path().filename() != "plan.json");
    }
    if (created && !finished) std::filesystem::remove_all(folder, ec);
    throw;
  }
}

}  // namespace

FitOutcome fit_to_checkpoint(const std::string& volume, const FitConfig& config, const std::filesystem::path& out,
                             const std::filesystem::path& log_csv, const Progress& progress,
                             const std::filesystem::path& start_path) {
  io::Stopwatch watch;  // the command's clock: gmf.time_budget_s bounds all of it
  const gmf::GmfOptions& gmf = config.get<&AppConfig::gmf>();
  gmf.validate();
  FitStart start;
  {  // a stack larger than gmf.max_memory (or asked to) is fitted in bricks
    const io::VolumeOptions& vo = config.get<&AppConfig::volume>();
    vo.validate();
    // Opened once, on every rank (a shared filesystem; a rank that cannot ends the
    // job before any work); the bricked fit reads it by regions.
    std::unique_ptr<io::VolumeSource> source;
    open_on_every_rank(job(), [&] { source = io::open_volume_source(volume, io::stack_read_options(vo)); });
    const io::WorldFrame frame = io::stack_frame(source->nx, source->ny, source->nz, source->spacing, vo.aspect, volume);
    if (!start_path.empty()) start = FitStart::load(start_path, frame);
    const gmf::FitPlanChoice choice =
        gmf::choose_fit_plan({source->nx, source->ny, source->nz}, frame, gmf, {}, job().size());
    if (choice.bricked) return fit_streamed(volume, *source, config, choice, start, out, log_csv, progress);
  }
  const FittedModel fitted =
      fit_loaded(io::load_volume(volume, config.get<&AppConfig::volume>()), volume, config, progress, &watch, start);
  const gmf::GaussianMixture& mixture = fitted.checkpoint.mixture;
  const gmf::FitResult& result = fitted.result;
  gmf::save_checkpoint(out, mixture, fitted.checkpoint.meta);
  if (!log_csv.empty()) {
    std::ostringstream s;
    s << fit_log_csv_header() << "\n";
    append_fit_log_csv(s, result.log, "");
    const std::string csv = s.str();
    io::write_file_atomic(log_csv, csv.data(), csv.size());
  }
  FitOutcome outcome{mixture.size(), result.final_psnr_3d, watch.elapsed(), result.stop_reason};
  progress.say("fit: wrote %s: K %zu (%d pruned), 3D PSNR %.2f dB, %s (%s)", out.c_str(), mixture.size(), result.pruned,
               result.final_psnr_3d, format_seconds(outcome.seconds).c_str(), result.stop_reason.c_str());
  return outcome;
}

FittedModel fit_loaded(io::LoadedVolume loaded, const std::string& source, const FitConfig& config,
                       const Progress& progress, const io::Stopwatch* command, const FitStart& start) {
  io::Stopwatch own;
  const io::Stopwatch& since = command != nullptr ? *command : own;
  config.get<&AppConfig::gmf>().validate();
  gmf::GmfOptions gmf = config.get<&AppConfig::gmf>();
  if (!start.empty()) gmf.beta_start = gmf.beta_end;  // the model was annealed already
  FitSetup setup = prepare_fit(std::move(loaded), source, config, "fit", progress, start);
  const bool sum = gmf.aggregation == gmf::Aggregation::kSum;
  const std::string jitter_source =
      gmf.sample_jitter ? "" : strf("auto for the %s: ", gmf::describe_aggregation(gmf.aggregation));
  const std::string objective = sum                                         ? std::string("sum (report Eq. 1)")
                                : gmf.aggregation == gmf::Aggregation::kMax ? std::string("max")
                                : gmf.final_aggregation() == gmf::Aggregation::kMax
                                    ? strf("softmax (beta %g -> %g), the last %g%% on the max", gmf.beta_start,
                                           gmf.beta_end, 100 * gmf.hard_share)
                                    : strf("softmax (beta %g -> %g)", gmf.beta_start, gmf.beta_end);
  progress.say("fit: %s objective; samples %s (gmf.sample_jitter %s%g)", objective.c_str(),
               gmf.jitter() > 0 ? "moved within their voxels each round" : "at the voxel centres",
               jitter_source.c_str(), gmf.jitter());
  // A raw stack's noise peaks are not structure: density control clones nothing that
  // the background's 99.9th percentile could explain.
  const gmf::BackgroundField background = stack_background(setup.loaded, config, progress);
  gmf::GmfOptions fit_options = gmf;
  fit_options.clone_floor = background.merged.none() ? 0.0 : background.merged.quantile(0.999);
  // gmf.time_budget_s bounds the command: loading, sampling, init and the background
  // are spent (the checkpoint's writing afterwards takes milliseconds).
  if (gmf.time_budget_s > 0) fit_options.time_budget_s = std::max(1e-3, gmf.time_budget_s - since.elapsed());
  gmf::GaussianMixture& mixture = setup.mixture;
  gmf::FitResult result = gmf::fit_mixture(setup.loaded.volume, setup.samples, setup.loaded.frame, mixture, fit_options,
                                           [&](const gmf::FitIteration& it) { report_iteration(it, progress); });
  for (const gmf::FitRound& r : result.rounds) {
    progress.say("fit: round %d density control: %d pruned, %d split, %d cloned -> K %d", r.round, r.pruned, r.split,
                 r.cloned, r.gaussians);
  }
  gmf::CheckpointMeta meta = checkpoint_meta(setup.loaded, source);
  meta.aggregation = gmf.final_aggregation();
  meta.beta = result.final_beta;
  if (!background.none()) record_background(setup.loaded.frame, config, background, meta, progress);
  return {{std::move(mixture), std::move(meta)}, result};
}

nlohmann::ordered_json FitStage::run(const RunRequest& request, const Config& config, bool, const Progress& progress) {
  const FitOutcome fit = fit_to_checkpoint(request.volume.string(), config, request.dir / "gmf.ply",
                                           request.dir / "fit_log.csv", progress);
  return {{"gaussians", fit.gaussians}, {"psnr_3d", fit.psnr_3d}, {"stop", fit.stop_reason}};
}

}  // namespace hisnegs::apps
