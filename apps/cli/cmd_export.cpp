// SPDX-License-Identifier: Apache-2.0
// `hisnegs export vdb|splat-ply|volume|compact|html --model m.ply -o OUT` and `hisnegs
// import vdb IN.vdb -o m.ply`: checkpoint conversion for OpenVDB tools, Gaussian-splat
// viewers, image viewers, small files and browsers. Options and reporting only; the
// conversions are gmf/export_*.hpp, gmf/compact_checkpoint.hpp and apps/viewer.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include "apps/cli/cli_support.hpp"
#include "apps/pipeline/format.hpp"
#include "apps/viewer/viewer_page.hpp"
#include "gmf/checkpoint.hpp"
#include "gmf/compact_checkpoint.hpp"
#include "gmf/export_formats.hpp"
#include "gmf/export_vdb.hpp"
#include "gmf/psnr.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/load_volume.hpp"
#include "io/memory_limit.hpp"
#include "io/stack_file.hpp"
#include "io/tiff_stack.hpp"
#include "io/timer.hpp"
#include "splat/camera.hpp"

namespace hisnegs::apps {
namespace {

// Progress lines appear only once an export has run this long (small ones stay quiet).
constexpr double kProgressAfterSeconds = 2.0;

// The frame of the stack at `path` from its header alone (no pixels are read),
// with the spacing and aspect rules of the `volume` section, as load_volume would.
io::WorldFrame header_frame(const std::string& path, const io::VolumeOptions& options) {
  const io::StackHeader info = io::inspect_stack(path, io::stack_read_options(options));
  return io::WorldFrame(info.nx, info.ny, info.nz,
                        io::aspect_scales(info.nx, info.ny, info.nz, info.spacing, options.aspect));
}

// The model's own stack frame, or a one-line error saying what to give instead.
io::WorldFrame native_frame(const gmf::Checkpoint& checkpoint, const std::string& model, const char* instead) {
  const std::optional<io::WorldFrame> frame = gmf::model_frame(checkpoint.meta);
  if (!frame) {
    io::fail_input(model,
                   std::string("records no volume_shape / aspect, so its native voxels are unknown; give ") + instead);
  }
  return *frame;
}

std::string shape_text(const io::WorldFrame& frame) {
  const Eigen::Vector3i& n = frame.shape();
  return std::to_string(n.x()) + "x" + std::to_string(n.y()) + "x" + std::to_string(n.z());
}

// What an export evaluates: "softmax (beta B), support 16" / "sum, support 16" /
// "sum of every term (untruncated)".
std::string exported_function(const gmf::MixtureModel& model, bool untruncated_sum) {
  if (model.aggregation == gmf::Aggregation::kSum && untruncated_sum) return "sum of every term (untruncated)";
  return gmf::describe(model) + ", support " + io::number_text(model.cutoff);
}

struct VdbArgs {
  std::string model, out, match_volume;
  std::optional<double> voxel_size;
  gmf::VdbExportOptions options;
  VolumeOverrides overrides;
};

void run_export_vdb(const VdbArgs& args, GlobalOptions& global) {
  gmf::VdbExportOptions options = args.options;
  options.support = global.config().gmf.mahalanobis_cutoff;  // the model's support, as its fit had it
  options.validate();
  io::Stopwatch watch;
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(args.model);
  gmf::VoxelLattice lattice;
  std::optional<io::WorldFrame> frame;  // the stack whose voxels the lattice is, if any
  std::string lattice_text;
  if (args.voxel_size) {
    const double v = *args.voxel_size;
    if (!std::isfinite(v) || !(v > 0.0)) {
      throw io::InputError("--voxel-size = " + io::number_text(v) + ": must be a finite number > 0 (world units)");
    }
    lattice = gmf::VoxelLattice::aligned(v);
    lattice_text = "voxel size " + io::number_text(v) + " aligned to the world origin";
    if (const auto& a = checkpoint.meta.aspect) {
      lattice = lattice.clipped_to_box(Eigen::Vector3d((*a)[0], (*a)[1], (*a)[2]));
      lattice_text += ", within the model's stack box";
    }
  } else {
    if (!args.match_volume.empty()) {
      io::VolumeOptions volume = global.config().volume;
      args.overrides.apply(volume);
      frame = header_frame(args.match_volume, volume);
      gmf::require_same_world_box(checkpoint.meta, *frame, args.match_volume);
      lattice_text = "the voxels of " + args.match_volume;
    } else {
      frame = native_frame(checkpoint, args.model, "--voxel-size V or --match-volume VOLUME");
      lattice_text = "the model's native voxels";
    }
    lattice = gmf::VoxelLattice::of(*frame);
    lattice_text += " (" + shape_text(*frame) + ")";
  }
  const gmf::ExportProgress progress = [&](std::int64_t done, std::int64_t total) {
    if (global.quiet || watch.elapsed() < kProgressAfterSeconds) return;
    std::printf("export vdb: %3.0f %% of %lld leaves, %s\n",
                100.0 * static_cast<double>(done) / static_cast<double>(total), static_cast<long long>(total),
                format_seconds(watch.elapsed()).c_str());
    std::fflush(stdout);
  };
  const gmf::VdbExportReport r = gmf::export_vdb(args.out, checkpoint, lattice, options, args.model, progress);
  if (global.quiet) return;
  std::string dense;
  if (frame) {
    const Eigen::Vector3i& n = frame->shape();
    dense = ", dense float32 of the stack " + format_bytes(4.0 * n.x() * n.y() * n.z());
  }
  std::printf(
      "export vdb: wrote %s: `density` (the model's f: %s) on %s, %lld active voxels (f > %g) in %lld leaves of "
      "%lld reached, K %lld%s; file %s%s; rasterize %s%s, write %s\n",
      args.out.c_str(),
      exported_function(gmf::model_of(checkpoint.meta, options.support), options.untruncated_sum).c_str(),
      lattice_text.c_str(),
      static_cast<long long>(r.active_voxels), args.options.cutoff, static_cast<long long>(r.leaf_count),
      static_cast<long long>(r.candidate_leaves), static_cast<long long>(r.gaussians),
      args.options.points ? " + `gaussians` points" : "", format_bytes(static_cast<double>(r.file_bytes)).c_str(),
      dense.c_str(), format_seconds(r.rasterize_seconds).c_str(),
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
  io::Stopwatch watch;
  const gmf::Checkpoint checkpoint = gmf::load_checkpoint(args.model);
  std::optional<io::LoadedVolume> matched;
  io::WorldFrame frame;
  io::TiffWriteOptions tiff;
  if (!args.match_volume.empty()) {
    io::VolumeOptions volume = global.config().volume;
    args.overrides.apply(volume);
    matched = io::load_volume(args.match_volume, volume);
    frame = matched->frame;
    gmf::require_same_world_box(checkpoint.meta, frame, args.match_volume);
    const io::VoxelSpacing& s = matched->volume.spacing;
    const bool known = std::any_of(s.source.begin(), s.source.end(),
                                   [](io::SpacingSource src) { return src != io::SpacingSource::kDefault; });
    if (known) tiff.spacing_um = s.um;
  } else {
    frame = native_frame(checkpoint, args.model, "--match-volume VOLUME");
    if (checkpoint.meta.spacing_um) tiff.spacing_um = *checkpoint.meta.spacing_um;
    const Eigen::Vector3i& shape = frame.shape();
    io::check_allocation(args.model, 4.0 * shape.cast<double>().prod(),
                         "a float32 volume of its volume_shape " + std::to_string(shape.z()) + " x " +
                             std::to_string(shape.y()) + " x " + std::to_string(shape.x()));
  }
  const double t_load = watch.lap();
  const gmf::MixtureModel model = gmf::model_of(checkpoint.meta, global.config().gmf.mahalanobis_cutoff);
  const std::vector<float> f = gmf::rasterize_dense(checkpoint.mixture, model, frame, args.tail, args.untruncated_sum);
  const double t_raster = watch.lap();
  const Eigen::Vector3i& n = frame.shape();
  io::write_tiff_stack(args.out, f, n.x(), n.y(), n.z(), tiff);
  const double t_write = watch.lap();
  if (global.quiet) return;
  std::string psnr;
  if (matched) {
    char buf[256];
    std::snprintf(buf, sizeof buf, ", 3D PSNR %.2f dB against %s", gmf::psnr(f, matched->volume.voxels),
                  args.match_volume.c_str());
    psnr = buf;
  }
  std::printf("export volume: wrote %s: the model's f (%s), %s float32 (%s)%s; load %s, rasterize %s, write %s\n",
              args.out.c_str(), exported_function(model, args.untruncated_sum).c_str(), shape_text(frame).c_str(),
              format_bytes(4.0 * static_cast<double>(f.size())).c_str(), psnr.c_str(), format_seconds(t_load).c_str(),
              format_seconds(t_raster).c_str(), format_seconds(t_write).c_str());
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
  const gmf::CompactHeader h =
      gmf::save_compact_checkpoint(args.out, checkpoint.mixture, checkpoint.meta, args.options);
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
  ViewerPageSettings settings;
  settings.floor = splat::floors_of(checkpoint.meta, args.model, config.splat.background);
  settings.cutoff = config.splat.mahalanobis_cutoff;
  settings.low_pass = config.splat.low_pass;
  settings.um_per_world = um_per_world(checkpoint.meta);
  settings.model_block = args.float32 ? ViewerModelBlock::kFloat32 : ViewerModelBlock::kCompact;
  std::size_t block_bytes = 0;
  const std::string html = viewer_html(checkpoint.mixture, cameras, settings, &block_bytes);
  io::write_file_atomic(args.out, html.data(), html.size());
  if (global.quiet) return;
  const auto model_bytes = static_cast<double>(std::filesystem::file_size(args.model));
  const double k = std::max(1.0, static_cast<double>(checkpoint.mixture.size()));
  // The model block (what the Gaussians cost) and the page (the viewer's code too).
  std::printf(
      "export html: wrote %s: %s, %.1f B/Gaussian (%zu Gaussians; the model %s as %s, %.1f B/Gaussian, %.1f in "
      "base64; %s is %s), %zu views of %dx%d from %s; "
      "hard MIP, cutoff %g, low-pass %g px^2; open it with #view=N&ui=0 for view N; %s\n",
      args.out.c_str(), format_bytes(static_cast<double>(html.size())).c_str(), static_cast<double>(html.size()) / k,
      checkpoint.mixture.size(), format_bytes(static_cast<double>(block_bytes)).c_str(),
      args.float32 ? "float32" : "compact .hgs", static_cast<double>(block_bytes) / k,
      static_cast<double>((block_bytes + 2) / 3 * 4) / k, args.model.c_str(),
      format_bytes(model_bytes).c_str(), cameras.views.size(), cameras.intrinsics.width, cameras.intrinsics.height,
      args.cameras.empty() ? "the evaluation orbit" : args.cameras.c_str(), settings.cutoff, settings.low_pass,
      format_seconds(watch.elapsed()).c_str());
}

}  // namespace

void add_export_command(CLI::App& app, GlobalOptions& global) {
  auto* cmd = app.add_subcommand(
      "export",
      "convert a checkpoint: OpenVDB grids, splat-viewer PLY, dense TIFF stack, compact checkpoint, HTML viewer");
  cmd->require_subcommand(1);

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

  auto* volume = cmd->add_subcommand("volume", "the mixture resampled onto the voxel grid as a float32 TIFF stack");
  auto volume_args = std::make_shared<VolumeArgs>();
  volume->add_option("--model", volume_args->model, "checkpoint (.ply)")->required();
  volume->add_option("-o,--output", volume_args->out, "output .tif")->required();
  volume->add_option("--match-volume", volume_args->match_volume,
                     "resample onto this stack's voxels and report the 3D PSNR against it");
  volume->add_option("--tail", volume_args->tail, "leave out each Gaussian where its value is below this")
      ->capture_default_str();
  volume->add_flag("--untruncated-sum", volume_args->untruncated_sum,
                   "a sum checkpoint: every term everywhere (report Eq. 1), not the fitted f (terms inside gmf.mahalanobis_cutoff)");
  volume_args->overrides.add_to(volume);
  volume->callback([volume_args, &global] { run_export_volume(*volume_args, global); });

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
