// SPDX-License-Identifier: Apache-2.0
// describe_file: the kind from the file's first bytes, then one describer per kind.
#include "apps/pipeline/file_info.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string_view>

#include "apps/pipeline/format.hpp"
#include "apps/pipeline/halo_measure.hpp"
#include "gmf/core/checkpoint.hpp"
#include "gmf/core/compact_checkpoint.hpp"
#include "gmf/core/hierarchy_file.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/sparse_grid.hpp"
#include "io/stack_file.hpp"
#include "io/tiff_stack.hpp"
#include "io/timer.hpp"

namespace hisnegs::apps {
namespace {

enum class FileKind { kStack, kVdb, kPly, kCompact, kHierarchy };

FileKind detect_kind(const std::filesystem::path& path) {
  if (io::is_zarr_stack(path)) return FileKind::kStack;  // a folder: OME-Zarr or a Zarr array
  io::require_regular_file(path);
  std::ifstream in(path, std::ios::binary);
  unsigned char magic[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  in.read(reinterpret_cast<char*>(magic), 8);
  if ((magic[0] == 'I' && magic[1] == 'I' && (magic[2] == 42 || magic[2] == 43) && magic[3] == 0) ||
      (magic[0] == 'M' && magic[1] == 'M' && magic[2] == 0 && (magic[3] == 42 || magic[3] == 43))) {
    return FileKind::kStack;
  }
  if (magic[0] == 'p' && magic[1] == 'l' && magic[2] == 'y') return FileKind::kPly;
  if (io::is_hdf5_stack(path)) return FileKind::kStack;  // TIFF or HDF5: io::read_stack tells them apart
  if (gmf::has_compact_magic(std::string_view(reinterpret_cast<const char*>(magic), 8))) return FileKind::kCompact;
  if (gmf::has_hierarchy_magic(std::string_view(reinterpret_cast<const char*>(magic), 8))) return FileKind::kHierarchy;
  // OpenVDB files start with the int32 magic 0x56444220 (" BDV" little-endian).
  if (magic[0] == 0x20 && magic[1] == 0x42 && magic[2] == 0x44 && magic[3] == 0x56) return FileKind::kVdb;
  io::fail_input(path,
                 "unrecognized file type (expected a TIFF or HDF5 stack, an OME-Zarr folder, an OpenVDB .vdb, a .ply "
                 "or a compact .hgs checkpoint, or a .hgw hierarchy)");
}

// The bytes of every file under `folder`.
double folder_bytes(const std::filesystem::path& folder) {
  double bytes = 0;
  std::error_code ec;
  for (auto it = std::filesystem::recursive_directory_iterator(folder, ec); !ec && it != decltype(it)(); it.increment(ec)) {
    if (it->is_regular_file(ec)) bytes += static_cast<double>(it->file_size(ec));
  }
  return bytes;
}

std::string joined(const std::vector<long long>& v) {
  std::string s;
  for (const long long e : v) s += (s.empty() ? "" : "x") + std::to_string(e);
  return s;
}

// "%-12s %s" rows and free lines, in order.
class Sheet {
 public:
  explicit Sheet(FileInfo& info) : info_(info) {}
  void row(const std::string& key, const std::string& value) { info_.lines.push_back({key, value}); }
  template <class... A>
  void line(const char* format, A... args) {
    char buf[1024];
    std::snprintf(buf, sizeof buf, format, args...);
    std::string text = buf;
    if (!text.empty() && text.back() == '\n') text.pop_back();
    info_.lines.push_back({"", text});
  }

 private:
  FileInfo& info_;
};

std::string fmt(const char* f, double a) {
  char buf[128];
  std::snprintf(buf, sizeof buf, f, a);
  return buf;
}
std::string vec3(const Eigen::Vector3d& v) {
  char buf[128];
  std::snprintf(buf, sizeof buf, "(%.4g, %.4g, %.4g)", v.x(), v.y(), v.z());
  return buf;
}

void info_stack(const std::filesystem::path& path, const io::VolumeOptions& options, Sheet& sheet) {
  const io::StackReadOptions read = io::stack_read_options(options);
  const io::StackHeader header = io::inspect_stack(path, read);
  io::Stopwatch watch;
  io::Volume raw = io::read_stack(path, read);
  const double t_read = watch.lap();
  const io::VolumeStats raw_stats = io::compute_stats(raw, options.foreground_threshold);
  watch.lap();
  io::normalize(raw, options.normalization);  // in place: the raw statistics are taken
  const double t_norm = watch.lap();
  const io::Volume& volume = raw;

  sheet.row("file", path.string());
  sheet.row("format", header.format);
  if (io::is_zarr_stack(path)) {  // the pyramid: each level's shape, chunks, codecs, voxel size and size on disk
    const io::ZarrStackInfo zarr = io::inspect_zarr_stack(path, read.zarr());
    const std::filesystem::path group = zarr.pyramid.size() > 1 || !zarr.ome_version.empty() ? zarr.array.parent_path() : zarr.array;
    for (std::size_t l = 0; l < zarr.pyramid.size(); ++l) {
      const io::ZarrLevel& level = zarr.pyramid[l];
      const std::filesystem::path folder = zarr.pyramid.size() > 1 ? group / level.path : zarr.array;
      sheet.row(l == 0 ? "pyramid" : " ", "level " + std::to_string(l) + " (" + level.path + "): " + zarr.axes + " " +
                                              joined(level.shape) + ", chunks " + joined(level.chunks) + ", " +
                                              level.codecs + ", " + fmt("%.4g", level.scale_um[0]) + " x " +
                                              fmt("%.4g", level.scale_um[1]) + " x " + fmt("%.4g", level.scale_um[2]) +
                                              " um, " + format_bytes(folder_bytes(folder)) + " on disk" +
                                              (static_cast<int>(l) == zarr.level ? "  <- read" : ""));
    }
  }
  sheet.row("shape", "Z=" + std::to_string(raw.nz) + " Y=" + std::to_string(raw.ny) + " X=" + std::to_string(raw.nx) +
                         " (" + fmt("%.2f", raw.size() / 1e6) + " M voxels, " +
                         format_bytes(static_cast<double>(raw.size()) * 4.0) + " as float32)");
  sheet.row("spacing", raw.spacing.describe());
  const auto& s = raw.spacing.um;
  sheet.row("extent", fmt("%.4g", raw.nx * s[0]) + " x " + fmt("%.4g", raw.ny * s[1]) + " x " +
                          fmt("%.4g", raw.nz * s[2]) + " um");
  sheet.row("aspect", "physical " +
                          vec3(io::aspect_scales(raw.nx, raw.ny, raw.nz, raw.spacing, io::AspectMode::kPhysical)) +
                          ", shape (Eq. 9) " +
                          vec3(io::aspect_scales(raw.nx, raw.ny, raw.nz, raw.spacing, io::AspectMode::kShape)) +
                          "; using " + std::string(io::to_string(options.aspect)));
  sheet.row("intensity", "min " + fmt("%.6g", raw_stats.min) + ", max " + fmt("%.6g", raw_stats.max) + ", mean " +
                             fmt("%.4g", raw_stats.mean) + ", std " + fmt("%.4g", raw_stats.stddev));
  sheet.row("percentiles", "p1 " + fmt("%.6g", raw_stats.p01) + ", p50 " + fmt("%.6g", raw_stats.p50) + ", p99 " +
                               fmt("%.6g", raw_stats.p99) + ", p99.9 " + fmt("%.6g", raw_stats.p999));
  sheet.row("nonzero", fmt("%.3f %%", 100.0 * raw_stats.nonzero_fraction) + " of voxels differ from the minimum");
  sheet.row("foreground", fmt("%.3f %%", 100.0 * raw_stats.foreground_fraction) + " of voxels > min + " +
                              fmt("%.3g", options.foreground_threshold) + " (max - min)");
  sheet.row("normalized", volume.normalization.describe() + " -> [0, 1]" +
                              (volume.normalization.clipped_voxels
                                   ? " (" + std::to_string(volume.normalization.clipped_voxels) + " voxels clipped)"
                                   : ""));
  sheet.row("timing", "read " + format_seconds(t_read) + ", normalize " + format_seconds(t_norm));
}

void info_vdb(const std::filesystem::path& path, Sheet& sheet) {
  const auto grids = io::inspect_vdb(path);
  sheet.row("file", path.string());
  sheet.row("format", "OpenVDB, " + std::to_string(grids.size()) + " grid(s)");
  auto count = [](std::int64_t n) { return n < 0 ? std::string("?") : std::to_string(n); };
  for (const auto& g : grids) {
    sheet.line("grid '%s': %s %s, %s active voxels, %s leaves, %s, voxel size (%.4g, %.4g, %.4g)\n", g.name.c_str(),
               g.value_type.c_str(), g.grid_class.c_str(), count(g.active_voxels).c_str(), count(g.leaf_count).c_str(),
               g.memory_bytes < 0 ? "? bytes" : format_bytes(static_cast<double>(g.memory_bytes)).c_str(),
               g.voxel_size[0], g.voxel_size[1], g.voxel_size[2]);
    if (!g.values_read)
      sheet.line(
          "  values not loaded (OpenVDB's own %s format, which hisnegs cannot check first): "
          "counts as the writer recorded them\n",
          g.value_type.c_str());
    sheet.line("  active index bbox [%d %d %d] .. [%d %d %d]\n", g.bbox_min[0], g.bbox_min[1], g.bbox_min[2],
               g.bbox_max[0], g.bbox_max[1], g.bbox_max[2]);
    for (const auto& [key, value] : g.metadata) sheet.line("  %-22s %s\n", key.c_str(), value.c_str());
  }
}

// The "background" row (the merged distribution) and, for a background by region,
// the "bg regions" row.
void background_rows(const gmf::BackgroundField& field, Sheet& sheet) {
  const gmf::BackgroundModel& background = field.merged;
  if (field.none()) {
    sheet.row("background", "none recorded (renders draw no floor)");
  } else {
    char bg[200];
    std::snprintf(bg, sizeof bg,
                  "%zu levels of a ray sample, mean %.4g, p99 %.4g; %.3g samples per voxel of path: renders draw "
                  "its MIP floor (--background none: not)",
                  background.values.size(), background.mean(), background.quantile(0.99), background.samples_per_voxel);
    sheet.row("background", bg);
  }
  if (field.regional() && !field.none()) {
    const gmf::BackgroundField::Summary s = field.summary();
    const auto& c = field.regions.cells;
    sheet.row("bg regions", std::to_string(field.regions.count()) + " (" + std::to_string(c[0]) + " x " +
                                std::to_string(c[1]) + " x " + std::to_string(c[2]) + "), each its own floor; " +
                                std::to_string(s.subtracted) + " subtracted (floor 0); p99 " + fmt("%.4g", s.p99_lo) +
                                " to " + fmt("%.4g", s.p99_hi));
  }
}

// The hierarchy's own line: nodes, levels, pages and their size. `model` is what
// load_checkpoint read from the file (its leaf pages, checked); the other pages are
// decoded and checked here.
std::string hierarchy_text(const std::filesystem::path& path, const gmf::GaussianMixture& model) {
  const gmf::Hierarchy h = gmf::load_hierarchy_file(path, &model);
  const auto bytes = static_cast<double>(std::filesystem::file_size(path));
  const double k = static_cast<double>(std::max<std::size_t>(1, h.model_gaussians));
  return strf("hisnegs hierarchy (.hgw) version %u: %zu nodes on %d levels, %zu Gaussians in all pages for the "
              "model's %zu (its leaves), %s, %.2f B per model Gaussian; every page's CRC-32 matches",
              gmf::kHierarchyFormatVersion, h.nodes.size(), h.depth() + 1, h.gaussians.size(), h.model_gaussians,
              format_bytes(bytes).c_str(), bytes / k);
}

void info_checkpoint(const std::filesystem::path& path, FileKind kind, const std::filesystem::path& stack,
                     const io::VolumeOptions& options, Sheet& sheet) {
  const gmf::Checkpoint ckpt = gmf::load_checkpoint(path);
  const gmf::MixtureStats st = gmf::compute_stats(ckpt.mixture);
  sheet.row("file", path.string());
  if (kind == FileKind::kHierarchy) {
    sheet.row("format", hierarchy_text(path, ckpt.mixture));
  } else if (kind == FileKind::kCompact) {
    // load_checkpoint has read and checked the whole file; this reads its header again.
    const gmf::CompactHeader h = gmf::read_compact_header(io::read_file(path), path);
    const gmf::CompactBounds b = gmf::compact_bounds(h);
    char line[512];
    std::snprintf(line, sizeof line,
                  "compact (.hgs) version %u (%s): %s, %.2f B/Gaussian; bits position %d, log-scale %d, rotation %d, "
                  "intensity %d; largest errors position %.3g, log-scale %.3g, quaternion %.3g, intensity %.3g",
                  h.version, h.checksummed ? "CRC-32 of the whole file matches" : "no checksum: an older file",
                  format_bytes(static_cast<double>(h.file_bytes)).c_str(),
                  h.count ? static_cast<double>(h.file_bytes) / static_cast<double>(h.count) : 0.0,
                  h.bits.position_bits, h.bits.scale_bits, h.bits.rotation_bits, h.bits.intensity_bits,
                  std::max({b.position[0], b.position[1], b.position[2]}),
                  std::max({b.log_scale[0], b.log_scale[1], b.log_scale[2]}), b.rotation, b.intensity);
    sheet.row("format",
              "hisnegs " + std::string(line) + "; metadata format version " + std::to_string(ckpt.meta.format_version));
  } else {
    sheet.row("format", "hisnegs checkpoint (PLY), format version " + std::to_string(ckpt.meta.format_version));
  }
  sheet.row("gaussians", std::to_string(st.count) + " (" +
                             format_bytes(static_cast<double>(st.count) * gmf::kGaussianParamCount * 4.0) +
                             " of parameters)");
  if (ckpt.meta.volume_shape_zyx) {
    const auto& v = *ckpt.meta.volume_shape_zyx;
    sheet.row("volume", "Z=" + std::to_string(v[0]) + " Y=" + std::to_string(v[1]) + " X=" + std::to_string(v[2]));
  }
  if (ckpt.meta.spacing_um) {
    const auto& s = *ckpt.meta.spacing_um;
    sheet.row("spacing", vec3(Eigen::Vector3d(s[0], s[1], s[2])) + " um");
  }
  if (ckpt.meta.aspect) {
    const auto& a = *ckpt.meta.aspect;
    sheet.row("aspect", vec3(Eigen::Vector3d(a[0], a[1], a[2])));
  }
  if (!ckpt.meta.normalization.empty()) sheet.row("normalized", ckpt.meta.normalization);
  for (const auto& [k, v] : ckpt.meta.extra) {
    if (!k.starts_with("background")) sheet.row(k, v);  // summarized below
  }
  if (st.count == 0) return;
  sheet.row("mean scale", vec3(Eigen::Vector3d(st.mean_scale[0], st.mean_scale[1], st.mean_scale[2])) + " world units");
  char needles[160];
  std::snprintf(needles, sizeof needles, "%zu (%.2f %% of K) with an axis ratio above %g; the largest ratio %.3g",
                st.needles, st.count ? 100.0 * static_cast<double>(st.needles) / static_cast<double>(st.count) : 0.0,
                gmf::kNeedleAxisRatio, st.largest_axis_ratio);
  sheet.row("needles", needles);
  if (!stack.empty()) sheet.row("halos", halo_text(count_model_halos(ckpt, stack, options)));
  background_rows(gmf::background_field_of(ckpt.meta, path.string()), sheet);
  sheet.row("intensity", "a in [" + fmt("%.4g", st.intensity_min) + ", " + fmt("%.4g", st.intensity_max) + "], mean " +
                             fmt("%.4g", st.intensity_mean));
  sheet.line("%-16s %12s %12s %12s\n", "parameter", "min", "max", "mean");
  for (std::size_t i = 0; i < gmf::kGaussianParamCount; ++i) {
    const auto& r = st.params[i];
    sheet.line("%-16s %12.5g %12.5g %12.5g\n", std::string(gmf::kGaussianParamNames[i]).c_str(), r.min, r.max, r.mean);
  }
}

}  // namespace

std::string FileInfo::text() const {
  std::string out;
  for (const Line& line : lines) {
    if (line.key.empty()) {
      out += line.text;
    } else {
      char key[64];
      std::snprintf(key, sizeof key, "%-12s ", line.key.c_str());
      out += key + line.text;
    }
    out += '\n';
  }
  return out;
}

FileInfo describe_file(const std::filesystem::path& path, const io::VolumeOptions& volume,
                       const std::filesystem::path& stack) {
  FileInfo info;
  Sheet sheet(info);
  const FileKind kind = detect_kind(path);
  if (!stack.empty() && kind != FileKind::kPly && kind != FileKind::kCompact && kind != FileKind::kHierarchy) {
    io::fail_input(path,
                   "is not a checkpoint: --volume (the stack to count halos against) is for a .ply, .hgs or .hgw");
  }
  switch (kind) {
    case FileKind::kStack:
      info.kind = "stack";
      info_stack(path, volume, sheet);
      break;
    case FileKind::kVdb:
      info.kind = "vdb";
      info_vdb(path, sheet);
      break;
    case FileKind::kPly:
      info.kind = "checkpoint";
      info_checkpoint(path, kind, stack, volume, sheet);
      break;
    case FileKind::kCompact:
      info.kind = "compact checkpoint";
      info_checkpoint(path, kind, stack, volume, sheet);
      break;
    case FileKind::kHierarchy:
      info.kind = "hierarchy";
      info_checkpoint(path, kind, stack, volume, sheet);
      break;
  }
  return info;
}

}  // namespace hisnegs::apps
