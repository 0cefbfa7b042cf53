// SPDX-License-Identifier: Apache-2.0
// export_model_*: the lattice or voxels an export uses, the conversion, the file.
#include "apps/pipeline/export_model.hpp"

#include <algorithm>
#include <cmath>

#include "gmf/core/export_formats.hpp"
#include "gmf/core/psnr.hpp"
#include "gmf/core/rasterize.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"
#include "io/stack_file.hpp"
#include "io/tiff_stack.hpp"
#include "io/zarr_stack.hpp"
#include "io/timer.hpp"
#include "splat/background_floor.hpp"

namespace hisnegs::apps {
namespace {

// The frame of the stack at `path` from its header alone (no pixels are read),
// with the spacing and aspect rules of the `volume` section, as load_volume would.
io::WorldFrame header_frame(const std::filesystem::path& path, const io::VolumeOptions& options) {
  const io::StackHeader info = io::inspect_stack(path, io::stack_read_options(options));
  return io::WorldFrame(info.nx, info.ny, info.nz,
                        io::aspect_scales(info.nx, info.ny, info.nz, info.spacing, options.aspect));
}

// The model's own stack frame, or a one-line error saying what to give instead.
io::WorldFrame native_frame(const gmf::Checkpoint& checkpoint, const std::string& model, const std::string& instead) {
  const std::optional<io::WorldFrame> frame = gmf::model_frame(checkpoint.meta);
  if (!frame) {
    io::fail_input(model,
                   "records no volume_shape / aspect, so its native voxels are unknown; give " + instead);
  }
  return *frame;
}

// `out` must not be the stack an export reads (`match_volume`): the CLI refuses that
// before any work; a library caller (the Python module) is refused here.
void refuse_to_overwrite(const std::filesystem::path& out, const std::filesystem::path& match_volume) {
  if (match_volume.empty()) return;
  const io::StackIdentity input = io::stack_identity(match_volume);  // a BigDataViewer .xml: its .h5 too
  if (input.holds(out)) {
    io::fail_input(out, "is also the volume to match" +
                            (io::same_file(match_volume, out) ? std::string() : " (" + match_volume.string() + " reads it)") +
                            "; refusing to overwrite it (choose another output)");
  }
}

// An output named X.zarr or X.ome.zarr is written as OME-Zarr.
bool is_zarr_path(const std::filesystem::path& out) { return out.extension() == ".zarr"; }

}  // namespace

std::string shape_text(const io::WorldFrame& frame) {
  const Eigen::Vector3i& n = frame.shape();
  return std::to_string(n.x()) + "x" + std::to_string(n.y()) + "x" + std::to_string(n.z());
}

std::string exported_function(const gmf::MixtureModel& model, bool untruncated_sum) {
  if (model.aggregation == gmf::Aggregation::kSum && untruncated_sum) return "sum of every term (untruncated)";
  return gmf::describe(model) + ", support " + io::number_text(model.cutoff);
}

VdbExportDone export_model_vdb(const gmf::Checkpoint& checkpoint, const std::string& model_name,
                               const std::filesystem::path& out, const VdbExportRequest& request,
                               const gmf::ExportProgress& progress) {
  request.options.validate();
  refuse_to_overwrite(out, request.match_volume);
  VdbExportDone done;
  gmf::VoxelLattice lattice;
  if (request.voxel_size) {
    const double v = *request.voxel_size;
    if (!std::isfinite(v) || !(v > 0.0)) {
      throw io::InputError("voxel_size = " + io::number_text(v) + ": must be a finite number > 0 (world units)");
    }
    if (!request.match_volume.empty()) {
      throw io::InputError("voxel_size and match_volume: give one of them, not both");
    }
    lattice = gmf::VoxelLattice::aligned(v);
    done.lattice = "voxel size " + io::number_text(v) + " aligned to the world origin";
    if (const auto& a = checkpoint.meta.aspect) {
      lattice = lattice.clipped_to_box(Eigen::Vector3d((*a)[0], (*a)[1], (*a)[2]));
      done.lattice += ", within the model's stack box";
    }
  } else {
    if (!request.match_volume.empty()) {
      done.frame = header_frame(request.match_volume, request.volume);
      gmf::require_same_world_box(checkpoint.meta, *done.frame, request.match_volume.string());
      done.lattice = "the voxels of " + request.match_volume.string();
    } else {
      done.frame = native_frame(checkpoint, model_name, request.instead);
      done.lattice = "the model's native voxels";
    }
    lattice = gmf::VoxelLattice::of(*done.frame);
    done.lattice += " (" + shape_text(*done.frame) + ")";
  }
  done.report = gmf::export_vdb(out, checkpoint, lattice, request.options, model_name, progress);
  done.function = exported_function(gmf::model_of(checkpoint.meta, request.options.support),
                                    request.options.untruncated_sum);
  return done;
}

VolumeExportDone export_model_volume(const gmf::Checkpoint& checkpoint, const std::string& model_name,
                                     const std::filesystem::path& out, const VolumeExportRequest& request) {
  if (!(request.tail > 0.0 && request.tail < 1.0)) {
    throw io::InputError("tail = " + io::number_text(request.tail) + ": must be in (0, 1)");
  }
  refuse_to_overwrite(out, request.match_volume);
  io::Stopwatch watch;
  VolumeExportDone done;
  std::optional<io::LoadedVolume> matched;
  io::TiffWriteOptions tiff;
  if (!request.match_volume.empty()) {
    matched = io::load_volume(request.match_volume, request.volume);
    done.frame = matched->frame;
    gmf::require_same_world_box(checkpoint.meta, done.frame, request.match_volume.string());
    const io::VoxelSpacing& s = matched->volume.spacing;
    const bool known = std::any_of(s.source.begin(), s.source.end(),
                                   [](io::SpacingSource src) { return src != io::SpacingSource::kDefault; });
    if (known) tiff.spacing_um = s.um;
  } else {
    done.frame = native_frame(checkpoint, model_name, request.instead);
    if (checkpoint.meta.spacing_um) tiff.spacing_um = *checkpoint.meta.spacing_um;
    const Eigen::Vector3i& shape = done.frame.shape();
    io::check_allocation(model_name, 4.0 * shape.cast<double>().prod(),
                         "a float32 volume of its volume_shape " + std::to_string(shape.z()) + " x " +
                             std::to_string(shape.y()) + " x " + std::to_string(shape.x()));
  }
  done.load_seconds = watch.lap();
  const gmf::MixtureModel model = gmf::model_of(checkpoint.meta, request.support);
  done.function = exported_function(model, request.untruncated_sum);
  const std::vector<float> f =
      gmf::rasterize_dense(checkpoint.mixture, model, done.frame, request.tail, request.untruncated_sum);
  done.rasterize_seconds = watch.lap();
  const Eigen::Vector3i& n = done.frame.shape();
  if (is_zarr_path(out)) {  // a multiscale OME-Zarr pyramid, for napari and Neuroglancer beside the stack
    io::Volume v;
    v.nx = n.x(), v.ny = n.y(), v.nz = n.z();
    if (tiff.spacing_um) v.spacing.um = *tiff.spacing_um;
    v.voxels = f;
    io::write_ome_zarr(out, v);
  } else {
    io::write_tiff_stack(out, f, n.x(), n.y(), n.z(), tiff);
  }
  done.write_seconds = watch.lap();
  if (matched) done.psnr = gmf::psnr(f, matched->volume.voxels);
  return done;
}

gmf::CompactHeader export_model_compact(const gmf::Checkpoint& checkpoint, const std::filesystem::path& out,
                                        const gmf::CompactOptions& options) {
  options.validate();
  return gmf::save_compact_checkpoint(out, checkpoint.mixture, checkpoint.meta, options);
}

HtmlExportDone export_model_html(const gmf::Checkpoint& checkpoint, const std::string& model_name,
                                 const std::filesystem::path& out, const splat::CameraSet& cameras,
                                 const splat::SplatOptions& splat, bool float32) {
  HtmlExportDone done;
  ViewerPageSettings& settings = done.settings;
  settings.floor = splat::floors_of(checkpoint.meta, model_name, splat.background);
  settings.cutoff = splat.mahalanobis_cutoff;
  settings.low_pass = splat.low_pass;
  settings.um_per_world = um_per_world(checkpoint.meta);
  settings.model_block = float32 ? ViewerModelBlock::kFloat32 : ViewerModelBlock::kCompact;
  const std::string html = viewer_html(checkpoint.mixture, cameras, settings, &done.model_block_bytes);
  io::write_file_atomic(out, html.data(), html.size());
  done.page_bytes = html.size();
  return done;
}

}  // namespace hisnegs::apps
