// SPDX-License-Identifier: Apache-2.0
// run_cli and the shared option helpers of the hisnegs command line.
#include "apps/cli/cli_support.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <sstream>

#include "apps/cli/console_progress.hpp"
#include "apps/pipeline/distributed.hpp"
#include "apps/pipeline/interrupts.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/stack_file.hpp"

namespace hisnegs::apps {

AppConfig& GlobalOptions::config() {
  if (!config_) {
    config_ = load_app_config(config_path.empty() ? std::nullopt : std::optional<std::filesystem::path>(config_path));
  }
  return *config_;
}

Progress GlobalOptions::progress() const { return console_progress(quiet); }

void VolumeOverrides::add_to(CLI::App* command) {
  command->add_option("--spacing", spacing_um, "voxel size x,y,z in um (overrides the file)")->delimiter(',');
  command->add_option("--channel", channel, "channel of a multi-channel stack (0-based; BigDataViewer: the setup)")
      ->check(CLI::NonNegativeNumber);
  command->add_option("--dataset", dataset, "HDF5: the dataset holding the stack, e.g. /data (default: the only one)");
  command->add_option("--timepoint", timepoint, "HDF5 / OME-Zarr time series: the time point (0-based)")
      ->check(CLI::NonNegativeNumber);
  command->add_option("--level", level, "OME-Zarr: the multiscale level to read (0: full resolution)")
      ->check(CLI::Range(0, 64));
  command->add_option("--normalization", normalization, "minmax | percentile (default from config)");
  command->add_option("--aspect", aspect, "physical | shape (report Eq. 9)");
}

void VolumeOverrides::apply(io::VolumeOptions& options) const {
  if (!spacing_um.empty()) options.spacing_um = spacing_um;
  if (channel) options.channel = *channel;
  if (!dataset.empty()) options.dataset = dataset;
  if (timepoint) options.timepoint = *timepoint;
  if (level) options.level = *level;
  if (!normalization.empty()) io::set_enum_field(options, "normalization", normalization, "--normalization");
  if (!aspect.empty()) io::set_enum_field(options, "aspect", aspect, "--aspect");
  if (!spacing_um.empty() && spacing_um.size() != 3) {
    throw io::InputError("--spacing: expected 3 values x,y,z, got " + std::to_string(spacing_um.size()));
  }
  options.validate();
}

void StackReadingOverrides::add_to(CLI::App* command, const std::string& what) {
  command->add_option("--max-memory", max_memory,
                      "most memory it may use (default gmf.max_memory: auto = half the RAM; or 1GiB, 512MiB): a larger "
                      "stack is " + what + " in bricks, with the same result");
  command->add_option("--brick-voxels", brick_voxels, "bricks of this core edge (voxels) even when the stack fits")
      ->check(CLI::Range(1, 65536));
}

StackReading StackReadingOverrides::reading(const AppConfig& config) const {
  StackReading r;
  r.max_memory = max_memory ? *max_memory : config.gmf.max_memory;
  if (brick_voxels) r.brick_voxels = *brick_voxels;
  return r;
}

void BackgroundOverride::add_to(CLI::App* command) {
  command->add_option("--background", value,
                      "model | none: draw the MIP floor of the background the checkpoint records, or the Gaussians "
                      "alone (default from config: splat.background)");
}

void BackgroundOverride::apply(splat::SplatOptions& options) const {
  if (value.empty()) return;
  if (value != "model" && value != "none") {
    throw io::InputError("--background = '" + io::printable(value, 40) + "': expected model or none");
  }
  options.background = value == "model";
}

void LodOverride::add_to(CLI::App* command) {
  command->add_option("--lod", pixels,
                      "draw each view from the model's level-of-detail hierarchy as the viewer would: a node's "
                      "coarser mixture wherever the detail it leaves out spans at most this many pixels (e.g. 1)");
  command->add_option("--lod-budget", budget, "with --lod: the most Gaussians a view draws (0: no limit)")
      ->capture_default_str();
}

std::optional<splat::LodOptions> LodOverride::options() const {
  if (!pixels) return std::nullopt;
  const splat::LodOptions lod{*pixels, budget};
  lod.validate();
  return lod;
}

CLI::Validator finite_number() {
  return CLI::Validator(
      [](std::string& text) -> std::string {
        try {
          std::size_t used = 0;
          const double v = std::stod(text, &used);
          if (used == text.size() && std::isfinite(v)) return {};
        } catch (const std::exception&) {
        }
        return "'" + io::printable(text, 40) + "' is not a finite number";
      },
      "FINITE");
}

namespace {

// Before a command does any work: its outputs (-o, --log) must not be an existing
// device, FIFO, socket or dangling symlink, nor the same file as any other value on
// its command line (the global options before the command included); every other
// value naming a regular file is protected for the run (io::protect_input), so no
// write can replace an input under another name.
void guard_outputs(const CLI::App& cmd) {
  std::vector<const CLI::Option*> outputs;
  for (const char* name : {"--output", "--log"}) {
    const CLI::Option* o = cmd.get_option_no_throw(name);
    if (o && o->count() > 0) outputs.push_back(o);
  }
  for (const CLI::Option* out : outputs) {
    for (const std::string& value : out->results()) {
      if (value.empty()) throw io::InputError(out->get_name() + ": empty path");
      std::error_code ec;
      const auto link = std::filesystem::symlink_status(value, ec);
      if (ec || !std::filesystem::exists(link)) continue;
      const auto target = std::filesystem::status(value, ec);
      if (!std::filesystem::exists(target)) io::fail_input(value, "is a symlink to nothing; refusing to replace it");
      if (!std::filesystem::is_regular_file(target) && !std::filesystem::is_directory(target)) {
        io::fail_input(value, "exists and is not a regular file (a device, FIFO or socket); refusing to replace it");
      }
    }
  }
  // Every value on the command line, the global options before the command
  // (--config FILE) included: a file a command reads is an input wherever it was named.
  std::vector<const CLI::Option*> values = cmd.get_options();
  for (const CLI::App* parent = cmd.get_parent(); parent != nullptr; parent = parent->get_parent()) {
    for (const CLI::Option* opt : parent->get_options()) values.push_back(opt);
  }
  for (const CLI::Option* opt : values) {
    if (std::find(outputs.begin(), outputs.end(), opt) != outputs.end()) continue;
    for (const std::string& value : opt->results()) {
      // Every file behind the value: a BigDataViewer .xml reads the .h5 it names;
      // an OME-Zarr folder holds every file under it.
      const io::StackIdentity input = io::stack_identity(value);
      for (const std::filesystem::path& file : input.files) {
        for (const CLI::Option* out : outputs) {
          for (const std::string& o : out->results()) {
            if (io::same_file(file, o) || (io::is_zarr_stack(file) && input.holds(o))) {
              io::fail_input(o, "is also an input (" + opt->get_name() +
                                    (file == value ? std::string() : " " + value + " reads it") +
                                    "); refusing to overwrite it");
            }
          }
        }
        io::protect_input(file);
      }
    }
  }
}

void guard_all_outputs(CLI::App& app) {
  for (CLI::App* sub : app.get_subcommands([](const CLI::App*) { return true; })) {
    sub->parse_complete_callback([sub] { guard_outputs(*sub); });
    guard_all_outputs(*sub);
  }
}

}  // namespace

namespace {

void add_commands(CLI::App& app, GlobalOptions& global) {
  add_demo_command(app, global);
  add_synth_command(app, global);
  add_noise_command(app, global);
  add_info_command(app, global);
  add_vdb_command(app, global);
  add_gt_command(app, global);
  add_fit_command(app, global);
  add_compare_command(app, global);
  add_render_command(app, global);
  add_eval_command(app, global);
  add_train_command(app, global);
  add_run_command(app, global);
  add_export_command(app, global);
  add_view_command(app, global);
  add_import_command(app, global);
  add_config_command(app, global);
  add_bench_command(app, global);
  guard_all_outputs(app);
}

// The command named on the command line ("" for none): CLI11 would only say "a
// subcommand is required" for a misspelt one, so it is named here (nullopt).
std::optional<std::string> command_of(CLI::App& app, int argc, char** argv) {
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--config") {
      ++i;
      continue;
    }
    if (arg.empty() || arg[0] == '-') continue;
    const auto subs = app.get_subcommands([](const CLI::App*) { return true; });
    if (std::none_of(subs.begin(), subs.end(), [&](const CLI::App* sub) { return sub->check_name(arg); })) {
      std::string names;
      for (const auto* sub : subs) names += (names.empty() ? "" : ", ") + sub->get_name();
      std::cerr << "hisnegs: error: unknown command '" << arg << "'; expected one of " << names << "\n";
      return std::nullopt;
    }
    return arg;
  }
  return std::string();
}

// The job of this process (MPI starts here, before any work, in a launch of several
// ranks), or nullptr after saying why not: MPI cannot start, or `command` does not
// run on several ranks.
const Job* start_job(const std::string& command) {
  const Job* the_job = nullptr;
  try {
    the_job = &job();
  } catch (const io::InputError& e) {
    std::cerr << "hisnegs: error: " << io::printable(e.what()) << "\n";
    return nullptr;
  }
  if (the_job->distributed() && command != "fit" && command != "gt" && command != "render" && command != "train" &&
      !command.empty()) {
    if (the_job->root()) {
      std::cerr << "hisnegs: error: '" << command << "' does not run on several MPI ranks (" << the_job->size()
                << " launched); fit, gt, render and train do; run it as one process\n";
    }
    return nullptr;
  }
  return the_job;
}

}  // namespace

int run_cli(int argc, char** argv) {
  install_interrupt_cleanup();
  CLI::App app{"hisnegs: Gaussian Mixture Field fitting and soft-MIP Gaussian splatting of microscopy volumes",
               "hisnegs"};
  app.set_version_flag("--version", std::string("hisnegs ") + HISNEGS_VERSION);
  app.require_subcommand(1);
  GlobalOptions global;
  app.add_option("--config", global.config_path, "YAML config (default: built-in = configs/default.yaml)");
  app.add_flag("-q,--quiet", global.quiet, "no progress output");
  add_commands(app, global);
  const std::optional<std::string> command = command_of(app, argc, argv);
  if (!command) return 2;
  const Job* the_job = start_job(*command);
  if (!the_job) return 2;
  // Each line in one write: on several ranks the launcher forwards the ranks' stderr
  // in the chunks they were written, between its own messages.
  const auto say = [](const std::string& line) { std::cerr << line; };
  const auto failed = [&](int code) {
    // A rank that fails ends the others (they may be waiting for it), saying which.
    if (the_job->distributed()) {
      say("hisnegs: " + rank_prefix(*the_job) + "stopping every rank\n");
      the_job->abort(code);
    }
    return code;
  };
  const std::string head = "hisnegs: " + rank_prefix(*the_job);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() == 0) return app.exit(e);  // --help, --version
    say(head + "error: " + io::printable(e.what()) + " (see hisnegs --help)\n");
    return failed(2);  // ranks launched with other arguments (MPMD) must not wait for this one
  } catch (const io::InputError& e) {
    say(head + "error: " + io::printable(e.what()) + "\n");
    return failed(2);
  } catch (const io::WriteError& e) {
    say(head + "error: " + io::printable(e.what()) + "\n");
    return failed(1);
  } catch (const std::bad_alloc&) {
    say(head + "error: out of memory\n");
    return failed(1);
  } catch (const std::exception& e) {
    say(head + "internal error: " + io::printable(e.what()) + "\n");
    return failed(1);
  }
  return 0;
}

}  // namespace hisnegs::apps
