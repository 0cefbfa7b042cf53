// SPDX-License-Identifier: Apache-2.0
// The conversions of `hisnegs export vdb|volume|compact|html` on a checkpoint in
// memory: what the CLI (apps/cli/cmd_export.cpp: options and its report line) and
// the Python module (hisnegs.export_*) both run.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "apps/viewer/viewer_page.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/core/compact_checkpoint.hpp"
#include "gmf/export_vdb.hpp"
#include "io/load_volume.hpp"
#include "splat/camera.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::apps {

// What an export evaluates: "softmax (beta B), support 16" / "sum, support 16" /
// "sum of every term (untruncated)".
std::string exported_function(const gmf::MixtureModel& model, bool untruncated_sum);

// "NXxNYxNZ" of a frame's voxels.
std::string shape_text(const io::WorldFrame& frame);

// export vdb: the voxels are cubic ones of `voxel_size` aligned to the world origin
// (within the model's box), those of `match_volume` (its header only; read with
// `volume`), or else the model's own stack's. options.support is the fit's
// gmf.mahalanobis_cutoff.
struct VdbExportRequest {
  std::optional<double> voxel_size;
  std::filesystem::path match_volume;
  io::VolumeOptions volume;
  gmf::VdbExportOptions options;
  // What the error for a model without its stack's frame tells the user to give.
  std::string instead = "a voxel size or a volume to match";
};
struct VdbExportDone {
  gmf::VdbExportReport report;
  std::string lattice;                  // "the model's native voxels (56x48x16)", ...
  std::optional<io::WorldFrame> frame;  // the stack whose voxels the lattice is, if any
  std::string function;                 // exported_function()
};
VdbExportDone export_model_vdb(const gmf::Checkpoint& checkpoint, const std::string& model_name,
                               const std::filesystem::path& out, const VdbExportRequest& request,
                               const gmf::ExportProgress& progress = {});

// export volume: the model's f at every voxel centre of `match_volume` (loaded with
// `volume`; the 3D PSNR against it is reported) or of the model's own stack, as a
// float32 TIFF stack with the stack's spacing. `support`: gmf.mahalanobis_cutoff.
struct VolumeExportRequest {
  std::filesystem::path match_volume;
  io::VolumeOptions volume;
  double tail = gmf::VdbExportOptions{}.tail;
  bool untruncated_sum = false;
  double support = gmf::VdbExportOptions{}.support;
  std::string instead = "a volume to match";  // as VdbExportRequest::instead
};
struct VolumeExportDone {
  io::WorldFrame frame;
  std::optional<double> psnr;  // against match_volume
  std::string function;
  double load_seconds = 0, rasterize_seconds = 0, write_seconds = 0;
};
VolumeExportDone export_model_volume(const gmf::Checkpoint& checkpoint, const std::string& model_name,
                                     const std::filesystem::path& out, const VolumeExportRequest& request);

// export compact: the .hgs of gmf/core/compact_checkpoint.hpp.
gmf::CompactHeader export_model_compact(const gmf::Checkpoint& checkpoint, const std::filesystem::path& out,
                                        const gmf::CompactOptions& options);

// export html: one self-contained viewer page with the model and `cameras` inside,
// drawn with `splat`'s cutoff, low-pass and background floor.
struct HtmlExportDone {
  std::size_t page_bytes = 0;
  std::size_t model_block_bytes = 0;  // the Gaussians' part of the page, before base64
  ViewerPageSettings settings;
};
HtmlExportDone export_model_html(const gmf::Checkpoint& checkpoint, const std::string& model_name,
                                 const std::filesystem::path& out, const splat::CameraSet& cameras,
                                 const splat::SplatOptions& splat, bool float32);

}  // namespace hisnegs::apps
