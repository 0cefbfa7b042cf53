// SPDX-License-Identifier: Apache-2.0
// `hisnegs export vdb|splat-ply|volume|compact|html --model m.ply -o OUT` and `hisnegs
// import vdb IN.vdb -o m.ply`: checkpoint conversion for OpenVDB tools, Gaussian-splat
// viewers, image viewers, small files and browsers. Options and reporting only; the
// conversions are apps/pipeline/export_model.hpp (shared with the Python module).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/export_model.hpp"
#include "apps/pipeline/format.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/core/compact_checkpoint.hpp"
#include "gmf/core/export_formats.hpp"
#include "gmf/core/hierarchy.hpp"
#include "gmf/core/hierarchy_file.hpp"
#include "gmf/export_vdb.hpp"
#include "io/error.hpp"
#include "io/timer.hpp"
#include "splat/camera.hpp"

namespace hisnegs::apps {
namespace {

// Bytes of base64 text for `bytes` bytes (4 characters per 3 bytes, the last group padded).
std::size_t base64_size(std::size_t bytes) { return (bytes + 2) / 3 * 4; }

// Progress lines appear only once an export has run this long (small ones stay quiet).
constexpr double kProgressAfterSeconds = 2.0;

struct VdbArgs {
  std::string model, out, match_volume;
  std::optional<double> voxel_size;
  gmf::VdbExportOptions options;
  VolumeOverrides overrides;
};

void run_export_vdb(const VdbArgs& args, GlobalOptions& global) {
  VdbExportRequest request;
  request.options = args.options;
  request.options.support = global.config().gmf.mahalanobis_cutoff;  // the model's support, as its fit had it
  request.options.validate();
  if (args.voxel_size && !(std::isfinite(*args.voxel_size) && *args.voxel_size > 0.0)) {
    throw io::InputError("--voxel-size = " + io::number_text(*args.voxel_size) +
                         ": must be a finite number > 0 (world units)");
  }
  request.voxel_size = args.voxel_size;
  request.match_volume = args.match_volume;
  request.volume = global.config().volume;
  args.overrides.apply(request.volume);
  request.instead = "--voxel-size V or --match-volume VOLUME";
  io::Stopwatch watch;
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(args.model);
  const gmf::ExportProgress progress = [&](std::int64_t done, std::int64_t total) {
    if (global.quiet || watch.elapsed() < kProgressAfterSeconds) return;
    std::printf("export vdb: %3.0f %% of %lld leaves, %s\n",
                100.0 * static_cast<double>(done) / static_cast<double>(total), static_cast<long long>(total),
                format_seconds(watch.elapsed()).c_str());
    std::fflush(stdout);
  };
  const VdbExportDone done = export_model_vdb(checkpoint, args.model, args.out, request, progress);
  if (global.quiet) return;
  const gmf::VdbExportReport& r = done.report;
  std::string dense;
  if (done.frame) {
    const Eigen::Vector3i& n = done.frame->shape();
    dense = ", dense float32 of the stack " + format_bytes(4.0 * n.x() * n.y() * n.z());
  }
  std::printf(
      "export vdb: wrote %s: `density` (the model's f: %s) on %s, %lld active voxels (f > %g) in %lld leaves of "
      "%lld reached, K %lld%s; file %s%s; rasterize %s%s, write %s\n",
      args.out.c_str(), done.function.c_str(), done.lattice.c_str(), static_cast<long long>(r.active_voxels),
      args.options.cutoff, static_cast<long long>(r.leaf_count), static_cast<long long>(r.candidate_leaves),
      static_cast<long long>(r.gaussians), args.options.points ? " + `gaussians` points" : "",
      format_bytes(static_cast<double>(r.file_bytes)).c_str(), dense.c_str(),
      format_seconds(r.rasterize_seconds).c_str(),
      args.options.points ? (", points " + format_seconds(r.points_seconds)).c_str() : "",
      format_seconds(r.write_seconds).c_str());
}

struct VolumeArgs {
  std::string model, out, match_volume;
  double tail = gmf::VdbExportOptions{}.tail;
  bool untruncated_sum = false;
  VolumeOverrides overrides;
};

void run_export_volume(const VolumeArgs& args, GlobalOptions& global) {
  if (!(args.tail > 0.0 && args.tail < 1.0)) {
    throw io::InputError("--tail = " + io::number_text(args.tail) + ": must be in (0, 1)");
  }
  VolumeExportRequest request;
  request.match_volume = args.match_volume;
  request.volume = global.config().volume;
  args.overrides.apply(request.volume);
  request.tail = args.tail;
  request.untruncated_sum = args.untruncated_sum;
  request.support = global.config().gmf.mahalanobis_cutoff;
  request.instead = "--match-volume VOLUME";
  io::Stopwatch watch;
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(args.model);
  const double t_checkpoint = watch.lap();
  const VolumeExportDone done = export_model_volume(checkpoint, args.model, args.out, request);
  if (global.quiet) return;
  std::string psnr;
  if (done.psnr) {
    char buf[256];
    std::snprintf(buf, sizeof buf, ", 3D PSNR %.2f dB against %s", *done.psnr, args.match_volume.c_str());
    psnr = buf;
  }
  const Eigen::Vector3i& n = done.frame.shape();
  std::printf("export volume: wrote %s: the model's f (%s), %s float32 (%s)%s; load %s, rasterize %s, write %s\n",
              args.out.c_str(), done.function.c_str(), shape_text(done.frame).c_str(),
              format_bytes(4.0 * n.cast<double>().prod()).c_str(), psnr.c_str(),
              format_seconds(t_checkpoint + done.load_seconds).c_str(),
              format_seconds(done.rasterize_seconds).c_str(), format_seconds(done.write_seconds).c_str());
}

struct CompactArgs {
  std::string model, out;
  gmf::CompactOptions options;
};

void run_export_compact(const CompactArgs& args, GlobalOptions& global) {
  args.options.validate();
  io::Stopwatch watch;
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(args.model);
  const double t_load = watch.lap();
  const gmf::CompactHeader h = export_model_compact(checkpoint, args.out, args.options);
  const double t_write = watch.lap();
  if (global.quiet) return;
  const double k = static_cast<double>(h.count);
  const auto in_bytes = static_cast<double>(std::filesystem::file_size(args.model));
  const auto out_bytes = static_cast<double>(h.file_bytes);
  const gmf::CompactBounds b = gmf::compact_bounds(h);
  const auto max3 = [](const std::array<double, 3>& v) { return std::max({v[0], v[1], v[2]}); };
  std::printf(
      "export compact: wrote %s: %zu Gaussians, %s (%.2f B/Gaussian; %s is %s, %.2f B/Gaussian: %.1fx smaller); "
      "bits position %d, log-scale %d, rotation %d, intensity %d; largest errors: position %.3g, log-scale %.3g, "
      "quaternion %.3g, intensity %.3g; load %s, encode and write %s\n",
      args.out.c_str(), static_cast<std::size_t>(h.count), format_bytes(out_bytes).c_str(), k > 0 ? out_bytes / k : 0.0,
      args.model.c_str(), format_bytes(in_bytes).c_str(), k > 0 ? in_bytes / k : 0.0, in_bytes / out_bytes,
      h.bits.position_bits, h.bits.scale_bits, h.bits.rotation_bits, h.bits.intensity_bits, max3(b.position),
      max3(b.log_scale), b.rotation, b.intensity, format_seconds(t_load).c_str(), format_seconds(t_write).c_str());
}

struct HierarchyArgs {
  std::string model, out;
  gmf::HierarchyOptions hierarchy;
  gmf::CompactOptions pages;
};

// export hierarchy: the model's level-of-detail hierarchy as a .hgw file.
void run_export_hierarchy(const HierarchyArgs& args, GlobalOptions& global) {
  args.hierarchy.validate();
  args.pages.validate();
  io::Stopwatch watch;
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(args.model);
  const gmf::Hierarchy h = gmf::build_hierarchy(checkpoint.mixture, args.hierarchy);
  const double t_build = watch.lap();
  const std::uint64_t bytes = gmf::save_hierarchy_file(args.out, h, checkpoint.meta, args.pages);
  if (global.quiet) return;
  const double k = static_cast<double>(std::max<std::size_t>(1, checkpoint.mixture.size()));
  std::printf("export hierarchy: wrote %s: %zu nodes on %d levels, %zu Gaussians in all for the model's %zu, %s "
              "(%.2f B per model Gaussian); load and build %s, encode and write %s\n",
              args.out.c_str(), h.nodes.size(), h.nodes.empty() ? 0 : h.depth() + 1, h.gaussians.size(),
              checkpoint.mixture.size(), format_bytes(static_cast<double>(bytes)).c_str(),
              static_cast<double>(bytes) / k, format_seconds(t_build).c_str(), format_seconds(watch.lap()).c_str());
}

struct HtmlArgs {
  std::string model, cameras, out;
  bool float32 = false;
  BackgroundOverride background;
};

// Without --cameras the page gets the evaluation orbit of the `camera` config section,
// so #view=N still names a definite camera.
void run_export_html(const HtmlArgs& args, GlobalOptions& global) {
  io::Stopwatch watch;
  AppConfig config = global.config();
  args.background.apply(config.splat);
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(args.model);
  const splat::CameraSet cameras =
      args.cameras.empty() ? splat::evaluation_orbit(config.camera) : splat::read_cameras_json(args.cameras);
  const HtmlExportDone done = export_model_html(checkpoint, args.model, args.out, cameras, config.splat, args.float32);
  if (global.quiet) return;
  const auto model_bytes = static_cast<double>(std::filesystem::file_size(args.model));
  const double k = std::max(1.0, static_cast<double>(checkpoint.mixture.size()));
  const auto page = static_cast<double>(done.page_bytes), block = static_cast<double>(done.model_block_bytes);
  // The model block (what the Gaussians cost) and the page (the viewer's code too).
  std::printf(
      "export html: wrote %s: %s, %.1f B/Gaussian (%zu Gaussians; the model %s as %s, %.1f B/Gaussian, %.1f in "
      "base64; %s is %s), %zu views of %dx%d from %s; "
      "hard MIP, cutoff %g, low-pass %g px^2; open it with #view=N&ui=0 for view N; %s\n",
      args.out.c_str(), format_bytes(page).c_str(), page / k, checkpoint.mixture.size(), format_bytes(block).c_str(),
      args.float32 ? "float32" : "compact .hgs", block / k,
      static_cast<double>(base64_size(done.model_block_bytes)) / k, args.model.c_str(),
      format_bytes(model_bytes).c_str(), cameras.views.size(), cameras.intrinsics.width, cameras.intrinsics.height,
      args.cameras.empty() ? "the evaluation orbit" : args.cameras.c_str(), done.settings.cutoff,
      done.settings.low_pass, format_seconds(watch.elapsed()).c_str());
}

// export vdb: the density grid (and the points).
void add_export_vdb(CLI::App* cmd, GlobalOptions& global) {
  auto* vdb = cmd->add_subcommand("vdb", "the mixture as a sparse OpenVDB `density` grid (+ `gaussians` points)");
  auto vdb_args = std::make_shared<VdbArgs>();
  vdb->add_option("--model", vdb_args->model, "checkpoint (.ply)")->required();
  vdb->add_option("-o,--output", vdb_args->out, "output .vdb")->required();
  auto* voxel =
      vdb->add_option("--voxel-size", vdb_args->voxel_size,
                      "cubic voxels of this world size, a voxel centre at the origin (within the model's box)");
  auto* match = vdb->add_option("--match-volume", vdb_args->match_volume,
                                "use the voxels of this TIFF stack (default: the model's own stack)");
  voxel->excludes(match);
  vdb->add_option("--cutoff", vdb_args->options.cutoff, "EPS: voxels with f <= EPS are inactive")
      ->capture_default_str();
  vdb->add_option("--tail", vdb_args->options.tail, "leave out each Gaussian where its value is below this")
      ->capture_default_str();
  vdb->add_flag("--points", vdb_args->options.points, "also write every Gaussian's parameters as a PointDataGrid");
  vdb->add_flag("--untruncated-sum", vdb_args->options.untruncated_sum,
                "a sum checkpoint: every term everywhere (report Eq. 1), not the fitted f (terms inside gmf.mahalanobis_cutoff)");
  vdb_args->overrides.add_to(vdb);
  vdb->callback([vdb_args, &global] { run_export_vdb(*vdb_args, global); });
}

// export splat-ply: a PLY for splatting viewers.
void add_export_splat_ply(CLI::App* cmd, GlobalOptions& global) {
  auto* splat = cmd->add_subcommand("splat-ply", "a PLY for 3D Gaussian-splatting viewers (a visual aid, not a MIP)");
  struct SplatArgs {
    std::string model, out, colormap = "grey";
    bool sh_rest = false;
  };
  auto splat_args = std::make_shared<SplatArgs>();
  splat->add_option("--model", splat_args->model, "checkpoint (.ply)")->required();
  splat->add_option("-o,--output", splat_args->out, "output .ply")->required();
  splat->add_option("--colormap", splat_args->colormap, "grey | fire: intensity -> colour")->capture_default_str();
  splat->add_flag("--sh-rest", splat_args->sh_rest, "also write f_rest_0..44 = 0 (viewers that need SH degree 3)");
  splat->callback([splat_args, &global] {
    gmf::SplatPlyOptions options;
    options.sh_rest = splat_args->sh_rest;
    if (splat_args->colormap == "fire") {
      options.colormap = gmf::SplatColormap::kFire;
    } else if (splat_args->colormap != "grey") {
      throw io::InputError("--colormap = '" + io::printable(splat_args->colormap, 40) + "': expected grey or fire");
    }
    const gmf::Checkpoint checkpoint = gmf::load_checkpoint(splat_args->model);
    gmf::write_splat_ply(splat_args->out, checkpoint.mixture, options);
    if (!global.quiet) {
      std::printf(
          "export splat-ply: wrote %s: %zu Gaussians, %s colours%s (a visual aid: viewers alpha-blend, "
          "they do not show a MIP)\n",
          splat_args->out.c_str(), checkpoint.mixture.size(), std::string(gmf::to_string(options.colormap)).c_str(),
          options.sh_rest ? ", SH degree 3 layout" : "");
    }
  });
}

// export volume: the mixture on a voxel grid.
void add_export_volume(CLI::App* cmd, GlobalOptions& global) {
  auto* volume = cmd->add_subcommand(
      "volume", "the mixture resampled onto the voxel grid as a float32 TIFF stack, or an OME-Zarr pyramid (-o X.ome.zarr)");
  auto volume_args = std::make_shared<VolumeArgs>();
  volume->add_option("--model", volume_args->model, "checkpoint (.ply)")->required();
  volume->add_option("-o,--output", volume_args->out, "output .tif, or .ome.zarr (a multiscale OME-Zarr v0.4 folder)")
      ->required();
  volume->add_option("--match-volume", volume_args->match_volume,
                     "resample onto this stack's voxels and report the 3D PSNR against it");
  volume->add_option("--tail", volume_args->tail, "leave out each Gaussian where its value is below this")
      ->capture_default_str();
  volume->add_flag("--untruncated-sum", volume_args->untruncated_sum,
                   "a sum checkpoint: every term everywhere (report Eq. 1), not the fitted f (terms inside gmf.mahalanobis_cutoff)");
  volume_args->overrides.add_to(volume);
  volume->callback([volume_args, &global] { run_export_volume(*volume_args, global); });
}

// export compact: the .hgs checkpoint.
void add_export_compact(CLI::App* cmd, GlobalOptions& global) {
  auto* compact = cmd->add_subcommand(
      "compact", "a compact checkpoint (.hgs: quantized, zstd) that every command reads like the .ply");
  auto compact_args = std::make_shared<CompactArgs>();
  gmf::CompactOptions& o = compact_args->options;
  compact->add_option("--model", compact_args->model, "checkpoint (.ply or .hgs)")->required();
  compact->add_option("-o,--output", compact_args->out, "output .hgs")->required();
  compact->add_option("--position-bits", o.position_bits, "bits per centre coordinate over the model's box")
      ->check(CLI::Range(8, 21))
      ->capture_default_str();
  compact->add_option("--scale-bits", o.scale_bits, "bits per log-scale over its range")
      ->check(CLI::Range(4, 16))
      ->capture_default_str();
  compact->add_option("--rotation-bits", o.rotation_bits, "bits per smallest-three quaternion component")
      ->check(CLI::Range(4, 15))
      ->capture_default_str();
  compact->add_option("--intensity-bits", o.intensity_bits, "bits of the intensity sigmoid(logit)")
      ->check(CLI::Range(4, 16))
      ->capture_default_str();
  compact->add_option("--level", o.zstd_level, "zstd compression level")
      ->check(CLI::Range(1, 22))
      ->capture_default_str();
  compact->callback([compact_args, &global] { run_export_compact(*compact_args, global); });
}

// export hierarchy: the level-of-detail file a streaming reader fetches by ranges.
void add_export_hierarchy(CLI::App* cmd, GlobalOptions& global) {
  auto* sub = cmd->add_subcommand(
      "hierarchy", "the model's level-of-detail hierarchy (.hgw: an index and a compact page per node), which "
                   "every command reads as the model");
  auto args = std::make_shared<HierarchyArgs>();
  sub->add_option("--model", args->model, "checkpoint (.ply, .hgs or .hgw)")->required();
  sub->add_option("-o,--output", args->out, "output .hgw")->required();
  sub->add_option("--page", args->hierarchy.page, "most Gaussians a node holds")
      ->check(CLI::Range(64, 1000000))
      ->capture_default_str();
  sub->callback([args, &global] { run_export_hierarchy(*args, global); });
}

// export html: the self-contained viewer page.
void add_export_html(CLI::App* cmd, GlobalOptions& global) {
  auto* html = cmd->add_subcommand(
      "html", "one self-contained HTML file: a WebGL2 hard-MIP viewer with the model and cameras inside");
  auto html_args = std::make_shared<HtmlArgs>();
  html->add_option("--model", html_args->model, "checkpoint (.ply or .hgs)")->required();
  html->add_option("--cameras", html_args->cameras, "cameras.json whose views #view=N shows (default: eval orbit)");
  html->add_option("-o,--output", html_args->out, "output .html")->required();
  html->add_flag("--float32", html_args->float32,
                 "embed exact float32 parameters instead of the compact .hgs encoding (about 3x larger)");
  html_args->background.add_to(html);
  html->callback([html_args, &global] { run_export_html(*html_args, global); });
}

}  // namespace

void add_export_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand(
      "export",
      "convert a checkpoint: OpenVDB grids, splat-viewer PLY, dense TIFF stack, compact checkpoint, LOD hierarchy, "
      "HTML viewer");
  cmd->require_subcommand(1);
  add_export_vdb(cmd, global);
  add_export_splat_ply(cmd, global);
  add_export_volume(cmd, global);
  add_export_compact(cmd, global);
  add_export_hierarchy(cmd, global);
  add_export_html(cmd, global);
}

void add_import_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand("import", "convert back to a checkpoint (from `export vdb --points`)");
  cmd->require_subcommand(1);
  auto* vdb = cmd->add_subcommand("vdb", "the `gaussians` points grid of a .vdb -> an identical checkpoint");
  struct Args {
    std::string in, out;
  };
  auto args = std::make_shared<Args>();
  vdb->add_option("VDB", args->in, ".vdb written by hisnegs export vdb --points")->required();
  vdb->add_option("-o,--output", args->out, "output checkpoint (.ply)")->required();
  vdb->callback([args, &global] {
    io::Stopwatch watch;
    const gmf::Checkpoint checkpoint = gmf::import_vdb_points(args->in);
    gmf::save_checkpoint(args->out, checkpoint.mixture, checkpoint.meta);
    if (!global.quiet) {
      std::printf("import vdb: wrote %s: %zu Gaussians from %s, %s\n", args->out.c_str(), checkpoint.mixture.size(),
                  args->in.c_str(), format_seconds(watch.elapsed()).c_str());
    }
  });
}

}  // namespace hisnegs::apps
