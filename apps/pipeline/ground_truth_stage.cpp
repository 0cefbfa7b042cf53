// SPDX-License-Identifier: Apache-2.0
// write_image_stack, the ground-truth sets and the run folder's ground-truth stage.
#include "apps/pipeline/ground_truth_stage.hpp"

#include <algorithm>
#include <cstdio>
#include <nlohmann/json.hpp>

#include "apps/pipeline/distributed.hpp"
#include "apps/pipeline/format.hpp"
#include "apps/pipeline/report_tables.hpp"
#include "gmf/bricked/memory_plan.hpp"
#include "io/atomic_file.hpp"
#include "io/png.hpp"
#include "io/stack_file.hpp"
#include "io/tiff_stack.hpp"
#include "io/timer.hpp"
#include "io/volume_source.hpp"
#include "splat/raymarch.hpp"
#include "splat/streamed_ground_truth.hpp"

namespace hisnegs::apps {
namespace {

// DIR/meta.json of a ground-truth set: the volume, its frame, the ray marcher and timing.
nlohmann::ordered_json ground_truth_meta(const io::LoadedVolume& loaded, const std::string& volume_path,
                                         const splat::RaymarchOptions& rm, const splat::MipStack& stack,
                                         double render_s) {
  nlohmann::ordered_json meta;
  const io::Volume& v = loaded.volume;
  meta["volume"] = volume_path;
  meta["volume_shape_zyx"] = {v.nz, v.ny, v.nx};
  meta["spacing_um"] = {v.spacing.um[0], v.spacing.um[1], v.spacing.um[2]};
  meta["spacing_source"] = v.spacing.describe();
  meta["normalization"] = {{"method", std::string(io::to_string(v.normalization.method))},
                           {"raw_lo", v.normalization.raw_lo},
                           {"raw_hi", v.normalization.raw_hi}};
  const Eigen::Vector3d& a = loaded.frame.aspect();
  meta["aspect"] = {a.x(), a.y(), a.z()};
  meta["mode"] = rm.mode == splat::RaymarchMode::kExact ? "exact" : "report";
  if (rm.mode == splat::RaymarchMode::kExact) {
    meta["step_world"] = splat::exact_step(loaded.frame, rm);
  } else {
    meta["samples"] = rm.samples;
    meta["t_near"] = rm.t_near;
    meta["t_far"] = rm.t_far;
  }
  meta["views"] = stack.views;
  meta["width"] = stack.width;
  meta["height"] = stack.height;
  meta["backend"] = std::string(splat::to_string(stack.backend));
  meta["timing"] = {{"render_s", render_s},
                    {"median_ms_per_view", 1e3 * median(stack.seconds_per_view)},
                    {"mean_ms_per_view", 1e3 * render_s / std::max(stack.views, 1)}};
  return meta;
}

}  // namespace

void write_image_stack(const std::filesystem::path& dir, const std::string& name, const splat::MipStack& stack) {
  io::TiffWriteOptions tiff;
  tiff.type = io::SampleType::kFloat32;
  io::write_tiff_stack(dir / name, stack.pixels, stack.width, stack.height, stack.views, tiff);
  for (int i = 0; i < stack.views; ++i) {
    char file[32];
    std::snprintf(file, sizeof file, "%03d.png", i);
    io::write_png(dir / "previews" / file, io::to_gray8(stack.view(i), stack.width, stack.height));
  }
}

namespace {

void write_set_files(const std::filesystem::path& dir, const std::string& label, const splat::CameraSet& cameras,
                     const io::LoadedVolume& loaded, const std::string& volume_path, const splat::RaymarchOptions& rm,
                     const splat::MipStack& stack, double render_s, const Progress& progress) {
  splat::write_cameras_json(dir / "cameras.json", cameras);
  write_image_stack(dir, "mips.tif", stack);
  nlohmann::ordered_json meta = ground_truth_meta(loaded, volume_path, rm, stack, render_s);
  meta["set"] = label;
  const std::string text = meta.dump(2) + "\n";
  io::write_file_atomic(dir / "meta.json", text.data(), text.size());
  progress.say("gt: %s: %d views of %dx%d (%s mode, %s) in %s, median %.1f ms/view -> %s", label.c_str(), stack.views,
               stack.width, stack.height, meta["mode"].get<std::string>().c_str(),
               std::string(splat::to_string(stack.backend)).c_str(), format_seconds(render_s).c_str(),
               1e3 * median(stack.seconds_per_view), dir.c_str());
}

}  // namespace

void write_ground_truth_set(const std::filesystem::path& dir, const std::string& label, const splat::CameraSet& cameras,
                            const io::LoadedVolume& loaded, const std::string& volume_path,
                            const RaymarchConfig& config, splat::Backend backend, const Progress& progress) {
  const splat::RaymarchOptions& rm = config.get<&AppConfig::raymarch>();
  rm.validate();
  io::Stopwatch watch;
  const splat::MipStack stack =
      splat::render_ground_truth(loaded.volume, loaded.frame, cameras, rm, backend, [&](int done, int total) {
        if (!progress.meter) return;
        const double per_view = watch.elapsed() / done;
        progress.meter(strf("gt %s: %d/%d views, %.1f ms/view, ETA %s", label.c_str(), done, total, per_view * 1e3,
                            format_seconds(per_view * (total - done)).c_str()),
                       done == total);
      });
  write_set_files(dir, label, cameras, loaded, volume_path, rm, stack, watch.lap(), progress);
}

namespace {

// The streamed sets: statistics in one pass, then each set brick by brick; `loaded`
// carries the stack's metadata only (no voxels) for meta.json.
void write_streamed_sets(const std::filesystem::path& dir, const std::filesystem::path& volume_path,
                         const std::vector<GroundTruthSet>& sets, const GroundTruthSetsConfig& config,
                         const Progress& progress, int core_voxels, const StackReading& reading) {
  const io::VolumeOptions& vo = config.get<&AppConfig::volume>();
  const splat::RaymarchOptions& rm = config.get<&AppConfig::raymarch>();
  vo.validate();
  rm.validate();
  io::Stopwatch watch;
  const Job& ranks = job();
  std::unique_ptr<io::VolumeSource> source;
  open_on_every_rank(ranks, [&] { source = io::open_volume_source(volume_path, io::stack_read_options(vo)); });
  io::LoadedVolume loaded;
  loaded.volume.nx = source->nx;
  loaded.volume.ny = source->ny;
  loaded.volume.nz = source->nz;
  loaded.volume.spacing = source->spacing;
  loaded.volume.stored_as = source->stored_as;
  loaded.volume.source = volume_path.string();
  // The ranks make the statistics pass together (or read the run's cache).
  loaded.volume.normalization =
      source_normalization(*source, vo, volume_path, reading, ranks.root() ? progress : Progress{}, scan_share(ranks));
  loaded.frame = io::stack_frame(source->nx, source->ny, source->nz, source->spacing, vo.aspect, volume_path);
  progress.say("gt: %s (X=%d Y=%d Z=%d) read by bricks of %d voxels: statistics (%s) in %s", volume_path.c_str(),
               source->nx, source->ny, source->nz, core_voxels, loaded.volume.normalization.describe().c_str(),
               format_seconds(watch.lap()).c_str());
  // Each rank marches every size-th brick; the images meet in an exact max on rank 0.
  const auto marches = [&](int brick) { return brick % ranks.size() == ranks.rank(); };
  for (const GroundTruthSet& set : sets) {
    splat::MipStack stack = splat::render_ground_truth_streamed(
        *source, loaded.volume.normalization, loaded.frame, set.cameras, rm, core_voxels,
        [&](int done, int total) {
          if (progress.meter) progress.meter(strf("gt %s: brick %d/%d", set.label.c_str(), done, total), done == total);
        },
        ranks.distributed() ? std::function<bool(int)>(marches) : std::function<bool(int)>{});
    if (ranks.distributed()) {
      ranks.max_to_root(stack.pixels);
      if (!ranks.root()) continue;
    }
    write_set_files(sets.size() > 1 ? dir / set.label : dir, set.label, set.cameras, loaded, volume_path.string(), rm,
                    stack, watch.lap(), progress);
  }
}

}  // namespace

int ground_truth_core(const std::array<int, 3>& shape, const StackReading& reading, const Progress& progress) {
  const int core = reading_core(shape, reading, BrickNeed{}, "gt", progress);
  const Job& ranks = job();
  if (!ranks.distributed()) return core;
  // Several MPI ranks share the bricks: two or more each, even when the stack fits.
  const int start = core > 0 ? core : *std::max_element(shape.begin(), shape.end());
  const int shared = gmf::core_for_ranks(shape, ranks.size(), start, std::min(16, start));
  progress.say("gt: %d MPI ranks share bricks of %d voxels", ranks.size(), shared);
  return shared;
}

void write_ground_truth_sets(const std::filesystem::path& dir, const std::filesystem::path& volume_path,
                             const std::vector<GroundTruthSet>& sets, const GroundTruthSetsConfig& config,
                             splat::Backend backend, const Progress& progress, int core_voxels,
                             const StackReading& reading) {
  if (core_voxels > 0) {
    write_streamed_sets(dir, volume_path, sets, config, progress, core_voxels, reading);
    return;
  }
  io::Stopwatch watch;
  const io::LoadedVolume loaded = io::load_volume(volume_path, config.get<&AppConfig::volume>());
  progress.say("gt: loaded %s (X=%d Y=%d Z=%d, aspect %.4g %.4g %.4g) in %s", volume_path.c_str(), loaded.volume.nx,
               loaded.volume.ny, loaded.volume.nz, loaded.frame.aspect().x(), loaded.frame.aspect().y(),
               loaded.frame.aspect().z(), format_seconds(watch.lap()).c_str());
  for (const GroundTruthSet& set : sets) {
    write_ground_truth_set(sets.size() > 1 ? dir / set.label : dir, set.label, set.cameras, loaded,
                           volume_path.string(), config.slice<&AppConfig::raymarch>(), backend, progress);
  }
}

std::filesystem::path ground_truth_set_dir(const std::filesystem::path& data, const std::string& set) {
  namespace fs = std::filesystem;
  if (fs::exists(data / set / "cameras.json")) return data / set;
  if (fs::exists(data / "cameras.json")) return data;
  io::fail_input(data, "no ground truth here: expected " + (data / set / "cameras.json").string() +
                           " (gt --orbit both) or " + (data / "cameras.json").string() +
                           " (gt with one set: --orbit train|eval|custom or --cameras)");
}

std::string ground_truth_set_label(const std::filesystem::path& dir) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(dir / "meta.json", ec)) return "";
  try {
    const nlohmann::json meta = nlohmann::json::parse(io::read_file(dir / "meta.json"));
    return meta.is_object() && meta.contains("set") && meta["set"].is_string() ? meta["set"].get<std::string>() : "";
  } catch (const std::exception&) {
    return "";  // a label only names the set in a message; the data is checked where it is read
  }
}

nlohmann::ordered_json GroundTruthStage::run(const RunRequest& request, const Config& config, bool,
                                             const Progress& progress) {
  const splat::CameraOptions& camera = config.get<&AppConfig::camera>();
  // Training: the orbit and the close views (camera.close_radii) in one set.
  splat::CameraSet train = splat::training_orbit(camera);
  for (splat::CameraView& view : splat::close_views(camera).views) train.views.push_back(std::move(view));
  const std::vector<GroundTruthSet> sets{{"train", std::move(train)}, {"eval", splat::evaluation_orbit(camera)}};
  const io::VolumeOptions& vo = config.get<&AppConfig::volume>();
  vo.validate();
  const io::StackHeader header = io::inspect_stack(request.volume, io::stack_read_options(vo));
  const int core = ground_truth_core({header.nx, header.ny, header.nz}, request.reading, progress);
  // bricks are marched on the CPU (as `gt` does)
  write_ground_truth_sets(request.dir / "gt", request.volume, sets,
                          config.slice<&AppConfig::volume, &AppConfig::raymarch>(),
                          core > 0 ? splat::Backend::kCpu : request.backend, progress, core, request.reading);
  return nullptr;
}

}  // namespace hisnegs::apps
