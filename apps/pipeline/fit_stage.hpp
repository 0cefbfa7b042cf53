// SPDX-License-Identifier: Apache-2.0
// The GMF stage (config sections volume, sparse_grid, gmf): initialization (grid or
// local maxima), the fit, the checkpoint (with its aggregation) and its log.
#pragma once

#include <filesystem>
#include <span>
#include <sstream>
#include <string>

#include "apps/pipeline/config_slice.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/run_stage.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/fit.hpp"
#include "io/load_volume.hpp"
#include "io/sparse_grid.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {

using FitConfig = ConfigSlice<&AppConfig::volume, &AppConfig::background, &AppConfig::sparse_grid, &AppConfig::gmf,
                              &AppConfig::raymarch>;

// Another fit of the same stack that a fit starts from (`fit --init`): a coarser
// level of its multiscale pyramid (each level fills the same world box) or an
// earlier fit. Its Gaussians replace gmf.init's (warm_start_mixture: those inside
// the box or brick, the brightest gmf.gaussians), and its β schedule starts at
// gmf.beta_end (the model was annealed already).
struct FitStart {
  std::filesystem::path path;  // empty: no warm start
  gmf::GaussianMixture model;  // in the stack's world coordinates
  std::string identity;        // a hash of the model, for a brick folder's fingerprint
  [[nodiscard]] bool empty() const { return path.empty(); }
  // Loads `path` and checks that it is a model of a stack of `frame`'s world box
  // (its aspect within 2 %: a pyramid level's rounding of odd shapes); io::InputError
  // naming the file otherwise.
  static FitStart load(const std::filesystem::path& path, const io::WorldFrame& frame);
  // The same check for a model in memory, named `name` in messages.
  static FitStart of(gmf::Checkpoint model, const io::WorldFrame& frame, const std::filesystem::path& name);
};

// What the GMF fit starts from: the normalized volume, its samples (from the
// sparse grid with the fit's background share, gmf.background_fraction; the grid
// itself is dropped once they are taken) and the mixture initialized on the
// foreground grid (sparse_grid.threshold, gmf.gaussians).
struct FitSetup {
  io::LoadedVolume loaded;
  gmf::SampleSet samples;
  std::int64_t active_voxels = 0;  // foreground + band voxels of the grid
  gmf::GaussianMixture mixture;
};
// Loads `volume_path` and prepares the fit; one line "LABEL: ...".
FitSetup prepare_fit(const std::string& volume_path, const FitConfig& config, const char* label,
                     const Progress& progress);
// The same for a volume already loaded (`name` says what it is in the line).
FitSetup prepare_fit(io::LoadedVolume loaded, const std::string& name, const FitConfig& config, const char* label,
                     const Progress& progress, const FitStart& start = {});

// The fit log as CSV rows: fit_log_csv_header() names the columns
// (iteration,seconds,loss,psnr_fg,psnr_3d,gaussians,round,beta; a PSNR is empty
// where it was not measured); each row starts with `prefix` and a comma when
// `prefix` is not empty (the optimizer comparison's curves).
std::string fit_log_csv_header();
void append_fit_log_csv(std::ostringstream& s, std::span<const gmf::FitIteration> log, const std::string& prefix);

// Checkpoint metadata of a model fitted to `loaded` (shape, spacing, aspect, normalization, source).
gmf::CheckpointMeta checkpoint_meta(const io::LoadedVolume& loaded, const std::string& source);
// The same for a stack read by regions: its frame (shape, aspect), spacing and map.
gmf::CheckpointMeta checkpoint_meta(const io::WorldFrame& frame, const io::VoxelSpacing& spacing,
                                    const io::Normalization& normalization, const std::string& source);

// The background of `loaded` by region (config section `background`); none, with
// one line saying why, when background.estimate is false or the background is 0.
gmf::BackgroundField stack_background(const io::LoadedVolume& loaded, const FitConfig& config, const Progress& progress);
// Calibrates `field` (not none) against the ray marcher (`raymarch`) and records it
// in `meta`, with one line.
void record_background(const io::WorldFrame& frame, const FitConfig& config, gmf::BackgroundField field,
                       gmf::CheckpointMeta& meta, const Progress& progress);

// prepare_fit(), the fit, the checkpoint `out` (with the stack's background,
// record_background; density control clones nothing below its 99.9th percentile) and, unless empty, the iteration log
// `log_csv`; a line per iteration report and density-control round, one at the end.
struct FitOutcome {
  std::size_t gaussians = 0;
  double psnr_3d = 0;  // of the final mixture against the normalized volume
  double seconds = 0;  // wall time including loading
  std::string stop_reason;
};
FitOutcome fit_to_checkpoint(const std::string& volume, const FitConfig& config, const std::filesystem::path& out,
                             const std::filesystem::path& log_csv, const Progress& progress,
                             const std::filesystem::path& start = {});

// The in-memory fit of fit_to_checkpoint without the files: the model with its
// checkpoint metadata (source `source`) and the fit's result (its log). What `fit`
// runs for a stack that fits in memory and what the Python module's hisnegs.fit runs.
struct FittedModel {
  gmf::Checkpoint checkpoint;
  gmf::FitResult result;
};
// gmf.time_budget_s counts from `command` (the command's clock, started before the
// volume was loaded) when given, else from the call.
FittedModel fit_loaded(io::LoadedVolume loaded, const std::string& source, const FitConfig& config,
                       const Progress& progress, const io::Stopwatch* command = nullptr, const FitStart& start = {});

// In a run folder: DIR/gmf.ply and DIR/fit_log.csv; reports {gaussians, psnr_3d,
// stop} as run.json's "fit".
struct FitStage {
  using Config = FitConfig;
  static constexpr const char* kName = "fit";
  static constexpr const char* kTitle = "GMF fit (stage 1)";
  static constexpr std::array<const char*, 1> kUpstream{"volume"};  // the volume file's identity
  static constexpr std::array<const char*, 2> kOutputs{"gmf.ply", "fit_log.csv"};
  static constexpr const char* kResumeMarker = "";
  static std::string request_inputs(const RunRequest&) { return {}; }
  static nlohmann::ordered_json run(const RunRequest& request, const Config& config, bool resume,
                                    const Progress& progress);
};

}  // namespace hisnegs::apps
