// SPDX-License-Identifier: Apache-2.0
// A stack that is read by regions instead of held whole: its shape, spacing, sample
// type and provenance, and read(box) of raw values. Implementations: a Volume in
// memory, a TIFF/BigTIFF file (the pages of the box's z range), an HDF5 file (a
// hyperslab: the chunks the box touches) and an OME-Zarr folder (the chunks or
// shard parts the box touches). Statistics for normalization come from one
// streaming pass over the source (exact for 8/16-bit stacks), so a stack larger than
// memory can be normalized as load_volume normalizes one that fits.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "io/stack_file.hpp"
#include "io/volume.hpp"

namespace hisnegs::io {

// Voxels [lo, hi) along x, y, z (half-open, index space).
struct VoxelBox {
  std::array<int, 3> lo{0, 0, 0};
  std::array<int, 3> hi{0, 0, 0};
  [[nodiscard]] std::size_t voxels() const {
    return static_cast<std::size_t>(hi[0] - lo[0]) * static_cast<std::size_t>(hi[1] - lo[1]) *
           static_cast<std::size_t>(hi[2] - lo[2]);
  }
};

class VolumeSource {
 public:
  virtual ~VolumeSource() = default;
  int nx = 0, ny = 0, nz = 0;
  SampleType stored_as = SampleType::kFloat32;
  VoxelSpacing spacing;
  std::string source;  // the path (or "memory")
  std::string format;  // as `info` shows it
  StackIdentity identity;  // every file behind it (none in memory): fingerprints and input guards use it
  // Raw values of `box` (inside the stack, not empty), x fastest, into `out`
  // (box.voxels() floats). Safe to call from several threads at once. Throws
  // InputError naming the file when it cannot be decoded, std::invalid_argument
  // for a box outside the stack.
  virtual void read(const VoxelBox& box, float* out) const = 0;
  [[nodiscard]] VoxelBox whole() const { return {{0, 0, 0}, {nx, ny, nz}}; }

 protected:
  void check_box(const VoxelBox& box) const;
};

// The source of a stack file (TIFF or HDF5, by its signature), header read and
// checked now, voxels on each read().
[[nodiscard]] std::unique_ptr<VolumeSource> open_volume_source(const std::filesystem::path& path,
                                                              const StackReadOptions& options = {});
// A Volume already in memory (raw or normalized values, as they are).
[[nodiscard]] std::unique_ptr<VolumeSource> memory_source(Volume volume);

// What normalization needs of a source, from one pass over z-slabs.
struct SourceStatistics {
  double min = 0.0, max = 0.0;
  std::int64_t voxels = 0;
  // 8/16-bit stacks: the count of every value (exact percentiles). float32: counts
  // of kFloatBins equal bins of bin_width over [min, max] from a second pass.
  std::vector<std::int64_t> histogram;
  double bin_width = 0.0;  // 0: one bin per integer value
  static constexpr std::size_t kFloatBins = std::size_t{1} << 20;
  // When the scan was given a CellGrid (8/16-bit stacks only): each cell's counts of
  // cell_bin(value), kCellBins per cell, cell after cell (z, then y, then x).
  static constexpr std::size_t kCellBins = 256;
  bool cell_log_bins = false;  // false: one bin per value (8-bit); true: 16 per octave (16-bit)
  std::vector<std::int64_t> cell_histograms;
  // The coarse bin of a stored value: the value itself (8-bit), or
  // floor(16 log2(value + 1)) (16-bit: bins 4.4 % wide whatever range a stack uses).
  [[nodiscard]] std::size_t cell_bin(std::size_t value) const;
  // The value at percentile p (0..100), interpolated between order statistics as
  // normalize() does: exact for 8/16-bit stacks; for float32 within one bin width
  // ((max - min) / 2^20) of normalize()'s value, each bin's ranks spread evenly
  // over it (and clipped_voxels is not counted).
  [[nodiscard]] double percentile(double p) const;
};
// The processes of a job scanning one stack together: process `part` of `parts`
// reads pages [nz·part/parts, nz·(part+1)/parts) and the partial results meet in
// `sum` (element-wise sums) and `max` (element-wise maxima), each leaving the
// whole's values on every process. The results are counts, minima and maxima,
// so they equal one process's exactly whatever `parts`. Alone: the defaults.
struct ScanShare {
  int part = 0, parts = 1;
  std::function<void(std::span<double>)> sum, max;
  [[nodiscard]] bool shared() const { return parts > 1; }
};

// A regular grid of cells over the stack (a streamed fit's brick cores): cells of
// `edge` voxels per axis (the last of an axis may be shorter), `count` per axis.
struct CellGrid {
  std::array<int, 3> edge{1, 1, 1};
  std::array<int, 3> count{1, 1, 1};
  [[nodiscard]] std::size_t cells() const {
    return static_cast<std::size_t>(count[0]) * static_cast<std::size_t>(count[1]) * static_cast<std::size_t>(count[2]);
  }
};

// Calls fn(box, values) for slabs of the stack in z order (of this part's pages
// when shared): whole pages while a page is under slab_bytes of float32, else
// bands of rows of one page. The pass every statistic here is made of.
void for_each_slab(const VolumeSource& source, std::size_t slab_bytes, const ScanShare& share,
                   const std::function<void(const VoxelBox& box, std::span<const float> values)>& fn);

// One streaming pass (two for float32): slabs of whole pages, or bands of rows of
// one page, each at most slab_bytes of float32; this part's pages when shared.
// With `cells` (an 8/16-bit stack), the same pass also takes each cell's coarse
// histogram (SourceStatistics::cell_histograms): what cell_counts_above estimates
// each cell's foreground from, without a pass of its own.
[[nodiscard]] SourceStatistics scan_statistics(const VolumeSource& source, std::size_t slab_bytes = 256u << 20,
                                               const ScanShare& share = {}, const CellGrid* cells = nullptr);

// The map normalize() would apply to the whole stack, from its statistics (the same
// errors: a constant stack, percentiles that coincide).
[[nodiscard]] Normalization normalization_from(const SourceStatistics& stats, const NormalizationOptions& options,
                                               const std::string& source);

// How many voxels are above `threshold` once normalized by `map`: exact from the
// histogram of an 8/16-bit stack, else (float32) one more pass of slabs.
[[nodiscard]] std::int64_t count_above(const VolumeSource& source, const SourceStatistics& stats,
                                       const Normalization& map, double threshold,
                                       std::size_t slab_bytes = 256u << 20);

// Each cell's voxels above `threshold` once normalized by `map`, from the cell
// histograms of `stats`: exact for an 8-bit stack, and for a 16-bit one exact but
// for the one coarse bin (4.4 % of values) the threshold falls in, whose voxels
// count in the whole stack's proportion above it. Throws std::logic_error without cell
// histograms.
[[nodiscard]] std::vector<std::int64_t> cell_counts_above(const SourceStatistics& stats, const Normalization& map,
                                                          double threshold);

}  // namespace hisnegs::io
