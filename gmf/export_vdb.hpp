// SPDX-License-Identifier: Apache-2.0
// Checkpoint -> OpenVDB (`hisnegs export vdb`): the mixture f(x) rasterized into a
// sparse `density` FloatGrid (gmf/core/rasterize.hpp's blocks are its leaves), optionally a `gaussians`
// PointDataGrid with every parameter of every Gaussian, and the way back from that
// points grid to a checkpoint (`hisnegs import vdb`). OpenVDB stays in the .cpp.
#pragma once

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <optional>
#include <string>

#include "gmf/core/checkpoint.hpp"
#include "gmf/core/rasterize.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

// How `export_vdb` rasterizes and what it writes.
struct VdbExportOptions {
  // EPS, normalized intensity in (0, 1): voxels with f <= cutoff are inactive (value 0,
  // the background), so the grid holds only the region where the model has signal.
  double cutoff = 1e-3;
  // Per-Gaussian truncation, in (0, cutoff]: Gaussian k is evaluated only where
  // a_k exp(-m/2) >= tail, i.e. inside m <= 2 ln(a_k / tail). Each stored value is
  // below the exact f by at most tail × (Gaussians reaching that voxel); 1e-8 keeps
  // that under 1e-6 for up to 100 overlapping Gaussians at ~6.1 σ support radius.
  double tail = 1e-8;
  // δ, > 0: the support m_k <= δ inside which a term counts in f (the fit's
  // gmf.mahalanobis_cutoff), for a sum and a softmax alike: the grid holds the
  // function that was fitted.
  double support = 16.0;
  // A sum checkpoint: count every term everywhere (report Eq. 1 without the support;
  // not the fitted f, which differs from it where Gaussians crowd). Metadata
  // untruncated_sum says which was written.
  bool untruncated_sum = false;
  // Also write the `gaussians` PointDataGrid (every parameter of every Gaussian).
  bool points = false;

  void validate() const;  // throws io::InputError("cutoff = VALUE: rule"), likewise tail
};

// What `export_vdb` made.
struct VdbExportReport {
  std::int64_t gaussians = 0;         // K
  std::int64_t candidate_leaves = 0;  // 8^3 leaves some Gaussian's support reaches
  std::int64_t leaf_count = 0;        // leaves kept (holding at least one voxel with f > cutoff)
  std::int64_t active_voxels = 0;     // voxels with f > cutoff
  std::size_t grid_memory_bytes = 0;  // both grids in memory, as OpenVDB counts it
  std::uintmax_t file_bytes = 0;      // size of the written .vdb
  double rasterize_seconds = 0;
  double points_seconds = 0;  // building the points grid (0 without points)
  double write_seconds = 0;
};

// Called from worker threads (serialized) with the leaves evaluated so far and the
// candidate total, about every 5 % of the work.
using ExportProgress = std::function<void(std::int64_t done, std::int64_t total)>;

// Writes `path` (atomically: temp file + rename, so no partial file on any throw)
// holding a FloatGrid `density` (class fog volume): the checkpoint's own f(x) (its
// aggregation: report Eq. 1 for a sum, f_β for a softmax; RasterizeOptions::exported)
// at the voxel centres of `lattice` inside lattice.clip, active where f >
// options.cutoff, with the lattice as its linear transform and metadata
// hisnegs_format_version, gaussians (K), cutoff, tail, aggregation (and for a
// softmax beta and support), model (= `model_source`), source (the checkpoint's
// `source`), clip_min/clip_max (when clipped) and, when the checkpoint records
// them, volume_shape_xyz, spacing_um, aspect, normalization.
// With options.points also a PointDataGrid `gaussians` (see import_vdb_points).
// Work and memory scale with the leaves the Gaussians' supports reach, never with
// their bounding box; values do not depend on the thread count (each voxel sums its
// Gaussians in checkpoint order). Throws io::InputError for invalid options or a
// lattice so fine that the supports would reach more leaves than memory holds
// (MemAvailable, or HISNEGS_MAX_ALLOC_GB GiB) or span more than 2^23 voxels along an
// axis; std::runtime_error naming `path` if writing fails.
VdbExportReport export_vdb(const std::filesystem::path& path, const Checkpoint& checkpoint, const VoxelLattice& lattice,
                           const VdbExportOptions& options, const std::string& model_source,
                           const ExportProgress& progress = {});

// Reads the `gaussians` PointDataGrid of a .vdb written by export_vdb with points:
// attributes `mean` (vec3f), `log_scale` (vec3f), `rotation` (float, stride 4, w x y
// z), `intensity_logit` (float) and `id` (int32, the Gaussian's row in the
// checkpoint, so the order is restored), plus the checkpoint's header lines in the
// grid metadata `hisnegs_checkpoint`. The result is bit-identical to the exported
// checkpoint (parameters and metadata). Throws io::InputError naming the file for a
// non-VDB, a missing grid, attribute or metadata, an attribute of another type,
// `id`s that are not 0..K-1 each once, and everything checkpoint_from_ply rejects.
[[nodiscard]] Checkpoint import_vdb_points(const std::filesystem::path& path);

}  // namespace hisnegs::gmf
