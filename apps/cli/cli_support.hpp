// SPDX-License-Identifier: Apache-2.0
// The hisnegs command line: subcommand registration, the shared options
// (--config, volume overrides), and error -> exit status mapping
// (bad input 2, internal failure 1). No computation here.
#pragma once

#include <CLI/CLI.hpp>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "apps/pipeline/app_config.hpp"
#include "apps/pipeline/progress.hpp"
#include "apps/pipeline/stack_reading.hpp"
#include "splat/lod.hpp"

namespace hisnegs::apps {

// Options every command may use; filled by CLI11 before a command's callback runs.
struct GlobalOptions {
  std::string config_path;  // --config FILE (empty: built-in defaults = configs/default.yaml)
  bool quiet = false;       // --quiet: no progress lines
  // The effective configuration (loaded on first use).
  AppConfig& config();
  // Where commands send progress: the console, or nowhere with --quiet.
  [[nodiscard]] Progress progress() const;

 private:
  std::optional<AppConfig> config_;
};

// What a VOLUME argument may be (every reader of io/stack_file.hpp), for --help.
inline constexpr const char* kStackHelp =
    "stack: TIFF/BigTIFF, HDF5 (.h5), BigDataViewer (.xml), Imaris (.ims), OME-Zarr or Zarr (a folder)";

// Command-line overrides of the `volume` section, shared by commands that read a stack.
struct VolumeOverrides {
  std::vector<double> spacing_um;  // --spacing X,Y,Z
  std::optional<int> channel;      // --channel C
  std::string dataset;             // --dataset /path (HDF5)
  std::optional<int> timepoint;    // --timepoint T (HDF5, OME-Zarr)
  std::optional<int> level;        // --level N (OME-Zarr multiscale)
  std::string normalization;       // --normalization minmax|percentile
  std::string aspect;              // --aspect physical|shape
  void add_to(CLI::App* command);
  // Applies the overrides to `options` and validates them.
  void apply(io::VolumeOptions& options) const;
};

// --max-memory and --brick-voxels of a command that reads the stack whole or by
// bricks (gt, vdb, train, run): the memory defaults to the config's gmf.max_memory.
struct StackReadingOverrides {
  std::optional<std::string> max_memory;
  std::optional<int> brick_voxels;
  // `what` ends the help text: what is read in bricks ("marched", "read").
  void add_to(CLI::App* command, const std::string& what);
  [[nodiscard]] StackReading reading(const AppConfig& config) const;
};

// `--background model|none` of the commands that render a checkpoint: draw the MIP
// floor of the background the checkpoint records (splat.background) or not.
struct BackgroundOverride {
  std::string value;  // "" = the config's splat.background
  void add_to(CLI::App* command);
  // Applies the flag to `options`; throws io::InputError for another word.
  void apply(splat::SplatOptions& options) const;
};

// --lod PIXELS and --lod-budget K of `render` and `eval`: each view drawn from the
// model's level-of-detail hierarchy (splat/lod.hpp).
struct LodOverride {
  std::optional<double> pixels;
  std::size_t budget = 0;
  void add_to(CLI::App* command);
  // The options when --lod was given (validated: io::InputError otherwise), else none.
  [[nodiscard]] std::optional<splat::LodOptions> options() const;
};

// Each registers one subcommand whose callback does the work.
void add_info_command(CLI::App& app, GlobalOptions& global);
void add_synth_command(CLI::App& app, GlobalOptions& global);
void add_noise_command(CLI::App& app, GlobalOptions& global);
void add_vdb_command(CLI::App& app, GlobalOptions& global);
void add_gt_command(CLI::App& app, GlobalOptions& global);
void add_fit_command(CLI::App& app, GlobalOptions& global);
void add_compare_command(CLI::App& app, GlobalOptions& global);
void add_render_command(CLI::App& app, GlobalOptions& global);
void add_eval_command(CLI::App& app, GlobalOptions& global);
void add_train_command(CLI::App& app, GlobalOptions& global);
void add_export_command(CLI::App& app, GlobalOptions& global);
void add_view_command(CLI::App& app, GlobalOptions& global);
void add_import_command(CLI::App& app, GlobalOptions& global);
void add_run_command(CLI::App& app, GlobalOptions& global);
void add_demo_command(CLI::App& app, GlobalOptions& global);
void add_config_command(CLI::App& app, GlobalOptions& global);
void add_bench_command(CLI::App& app, GlobalOptions& global);

// Entry point of the executable: parses, runs, maps errors to exit statuses and
// prints them as one line "hisnegs: error: ...".
int run_cli(int argc, char** argv);

// A CLI11 check that a value is a finite number (CLI::Range lets NaN through:
// every comparison with NaN is false).
CLI::Validator finite_number();

}  // namespace hisnegs::apps
