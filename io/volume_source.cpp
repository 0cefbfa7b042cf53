// SPDX-License-Identifier: Apache-2.0
// VolumeSource implementations (memory, TIFF slabs, HDF5 hyperslabs, Zarr chunks) and the
// streaming statistics pass.
#include "io/volume_source.hpp"

#include <algorithm>
#include <cmath>
#include <memory>
#include <mutex>
#include <numeric>
#include <sstream>
#include <stdexcept>

#include "io/error.hpp"

namespace hisnegs::io {
namespace {

void describe_into(VolumeSource& s, const Volume& v) {
  s.nx = v.nx;
  s.ny = v.ny;
  s.nz = v.nz;
  s.stored_as = v.stored_as;
  s.spacing = v.spacing;
  s.source = v.source.empty() ? "memory" : v.source;
}

class MemorySource final : public VolumeSource {
 public:
  explicit MemorySource(Volume v) : volume_(std::move(v)) {
    describe_into(*this, volume_);
    format = "in memory";
  }
  void read(const VoxelBox& box, float* out) const override {
    check_box(box);
    const std::size_t w = static_cast<std::size_t>(box.hi[0] - box.lo[0]);
    for (int z = box.lo[2]; z < box.hi[2]; ++z) {
      for (int y = box.lo[1]; y < box.hi[1]; ++y) {
        const float* row = volume_.voxels.data() + volume_.index(box.lo[0], y, z);
        out = std::copy(row, row + w, out);
      }
    }
  }

 private:
  Volume volume_;
};

// Concurrent reads share the page index (made by the first read, read-only after)
// and its pool of open handles, one handle per read at a time. A read goes to the
// pages of the box's z range by their offsets and decodes the strips/tiles it meets.
class TiffSource final : public VolumeSource {
 public:
  TiffSource(std::filesystem::path path, TiffReadOptions options) : path_(std::move(path)), options_(options) {}
  void read(const VoxelBox& box, float* out) const override {
    check_box(box);
    read_tiff_region(path_, options_, box.lo, box.hi, out, index().get());
  }

 private:
  // The index, made by the first read that needs it; a read that fails to make it
  // leaves none, and the next read tries again. (A mutex, not std::call_once: an
  // exception out of call_once can hang later callers in libstdc++, GCC PR 66146.)
  std::shared_ptr<const TiffPageIndex> index() const {
    const std::lock_guard<std::mutex> lock(index_mutex_);
    if (!index_) index_ = index_tiff_pages(path_, options_);
    return index_;
  }

  std::filesystem::path path_;
  TiffReadOptions options_;
  mutable std::mutex index_mutex_;
  mutable std::shared_ptr<const TiffPageIndex> index_;
};

// A source whose reader works from the header it inspected (HDF5, Zarr).
template <class Info, void (*kRead)(const Info&, const std::array<int, 3>&, const std::array<int, 3>&, float*)>
class InspectedSource final : public VolumeSource {
 public:
  explicit InspectedSource(Info info) : info_(std::move(info)) {}
  void read(const VoxelBox& box, float* out) const override {
    check_box(box);
    kRead(info_, box.lo, box.hi, out);
  }

 private:
  Info info_;
};
using Hdf5Source = InspectedSource<Hdf5StackInfo, read_hdf5_region>;
using ZarrSource = InspectedSource<ZarrStackInfo, read_zarr_region>;

}  // namespace

void VolumeSource::check_box(const VoxelBox& box) const {
  const std::array<int, 3> n{nx, ny, nz};
  for (int a = 0; a < 3; ++a) {
    if (box.lo[a] < 0 || box.hi[a] > n[a] || box.lo[a] >= box.hi[a]) {
      throw std::invalid_argument("VolumeSource::read: the box is empty or outside the stack (" + source + ")");
    }
  }
}

std::unique_ptr<VolumeSource> open_volume_source(const std::filesystem::path& path, const StackReadOptions& options) {
  std::unique_ptr<VolumeSource> s;
  StackHeader header;
  if (is_zarr_stack(path)) {
    const ZarrStackInfo info = inspect_zarr_for(path, options);
    header = header_of(info);
    s = std::make_unique<ZarrSource>(info);
  } else if (is_hdf5_stack(path)) {
    refuse_level(path, options);
    const Hdf5StackInfo info = inspect_hdf5_stack(path, options.hdf5());
    header = header_of(info);
    s = std::make_unique<Hdf5Source>(info);
  } else {
    header = inspect_stack(path, options);  // refuses --level too
    if (header.channels > 1 && !options.tiff.channel) {
      fail_input(path, "has " + std::to_string(header.channels) + " channels; choose one with --channel (0.." +
                           std::to_string(header.channels - 1) + ")");
    }
    if (header.nz < 2) fail_input(path, "has a single Z slice; expected a 3D stack");
    s = std::make_unique<TiffSource>(path, options.tiff);
  }
  s->nx = header.nx, s->ny = header.ny, s->nz = header.nz;
  s->stored_as = header.type;
  s->spacing = header.spacing;
  s->format = header.format;
  s->source = path.string();
  s->identity = stack_identity(path);
  return s;
}

std::unique_ptr<VolumeSource> memory_source(Volume volume) { return std::make_unique<MemorySource>(std::move(volume)); }

namespace {

// for_each_slab, with the callback inlined for the statistics' own passes.
template <class F>
void slabs_of(const VolumeSource& source, std::size_t slab_bytes, const ScanShare& share, F&& fn) {
  const std::size_t row = 4 * static_cast<std::size_t>(source.nx);
  const std::size_t page = row * static_cast<std::size_t>(source.ny);
  const int depth = static_cast<int>(std::clamp<std::size_t>(slab_bytes / page, 1, static_cast<std::size_t>(source.nz)));
  const int rows = page <= slab_bytes ? source.ny
                                      : static_cast<int>(std::clamp<std::size_t>(slab_bytes / row, 1,
                                                                                  static_cast<std::size_t>(source.ny)));
  const auto page_of = [&](int part) {
    return static_cast<int>(static_cast<std::int64_t>(source.nz) * part / std::max(1, share.parts));
  };
  const int z0 = page_of(share.part), z1 = page_of(share.part + 1);
  std::vector<float> block;
  for (int z = z0; z < z1; z += depth) {
    for (int y = 0; y < source.ny; y += rows) {
      const VoxelBox box{{0, y, z}, {source.nx, std::min(source.ny, y + rows), std::min(z1, z + depth)}};
      block.resize(box.voxels());
      source.read(box, block.data());
      fn(box, std::span<const float>(block));
    }
  }
}

// Counts summed over the parts (exact: doubles hold integers to 2^53).
void sum_counts(const ScanShare& share, std::span<std::int64_t> counts) {
  if (!share.shared()) return;
  std::vector<double> values(counts.begin(), counts.end());
  share.sum(values);
  for (std::size_t i = 0; i < counts.size(); ++i) counts[i] = static_cast<std::int64_t>(values[i]);
}

}  // namespace

void for_each_slab(const VolumeSource& source, std::size_t slab_bytes, const ScanShare& share,
                   const std::function<void(const VoxelBox& box, std::span<const float> values)>& fn) {
  slabs_of(source, slab_bytes, share, fn);
}

std::size_t SourceStatistics::cell_bin(std::size_t value) const {
  if (!cell_log_bins) return value;
  const auto b = static_cast<std::size_t>(std::floor(16.0 * std::log2(static_cast<double>(value) + 1.0)));
  return std::min(b, kCellBins - 1);
}

double SourceStatistics::percentile(double p) const {
  if (voxels == 0) return 0.0;
  if (p <= 0.0) return min;
  if (p >= 100.0) return max;
  if (histogram.empty()) throw std::logic_error("percentile: no histogram (scan_statistics did not build one)");
  // The order statistics k and k + 1 at pos = p/100 (n - 1), as percentiles_of().
  const double pos = p / 100.0 * static_cast<double>(voxels - 1);
  const auto k = static_cast<std::int64_t>(std::floor(pos));
  const bool binned = bin_width > 0;
  auto value_at_rank = [&](std::int64_t rank) {
    std::int64_t seen = 0;
    for (std::size_t v = 0; v < histogram.size(); ++v) {
      if (seen + histogram[v] > rank) {
        if (!binned) return static_cast<double>(v);
        // float32: ranks spread evenly over the bin
        const double within = (static_cast<double>(rank - seen) + 0.5) / static_cast<double>(histogram[v]);
        return std::min(max, min + (static_cast<double>(v) + within) * bin_width);
      }
      seen += histogram[v];
    }
    return max;
  };
  const double a = value_at_rank(k);
  const double b = k + 1 < voxels ? value_at_rank(k + 1) : a;
  return a + (pos - static_cast<double>(k)) * (b - a);
}

namespace {

// Per axis, each voxel coordinate's cell coordinate in `cells`.
std::array<std::vector<std::size_t>, 3> cell_coordinates(const VolumeSource& source, const CellGrid& cells) {
  const std::array<int, 3> n{source.nx, source.ny, source.nz};
  std::array<std::vector<std::size_t>, 3> of;
  for (int a = 0; a < 3; ++a) {
    of[a].resize(static_cast<std::size_t>(n[a]));
    for (int v = 0; v < n[a]; ++v) {
      of[a][static_cast<std::size_t>(v)] = static_cast<std::size_t>(std::min(v / cells.edge[a], cells.count[a] - 1));
    }
  }
  return of;
}

}  // namespace

SourceStatistics scan_statistics(const VolumeSource& source, std::size_t slab_bytes, const ScanShare& share,
                                 const CellGrid* cells) {
  SourceStatistics st;
  const bool integer = source.stored_as != SampleType::kFloat32;
  if (integer) st.histogram.assign(source.stored_as == SampleType::kUint8 ? 256 : 65536, 0);
  const bool by_cell = integer && cells != nullptr;
  std::array<std::vector<std::size_t>, 3> cell_of;
  std::vector<std::uint8_t> bin_of;  // cell_bin of every stored value
  if (by_cell) {
    st.cell_log_bins = source.stored_as != SampleType::kUint8;
    st.cell_histograms.assign(cells->cells() * SourceStatistics::kCellBins, 0);
    cell_of = cell_coordinates(source, *cells);
    bin_of.resize(st.histogram.size());
    for (std::size_t v = 0; v < bin_of.size(); ++v) bin_of[v] = static_cast<std::uint8_t>(st.cell_bin(v));
  }
  st.min = std::numeric_limits<double>::infinity();
  st.max = -std::numeric_limits<double>::infinity();
  slabs_of(source, slab_bytes, share, [&](const VoxelBox& box, std::span<const float> block) {
    const auto width = static_cast<std::size_t>(box.hi[0] - box.lo[0]);
    const auto height = static_cast<std::size_t>(box.hi[1] - box.lo[1]);
    for (std::size_t r = 0; r < block.size() / width; ++r) {
      std::int64_t* cell_row = nullptr;  // this row's cells' histograms (cell x at kCellBins · x)
      if (by_cell) {
        const std::size_t z = static_cast<std::size_t>(box.lo[2]) + r / height;
        const std::size_t y = static_cast<std::size_t>(box.lo[1]) + r % height;
        const auto cx = static_cast<std::size_t>(cells->count[0]), cy = static_cast<std::size_t>(cells->count[1]);
        cell_row = st.cell_histograms.data() + (cell_of[2][z] * cy + cell_of[1][y]) * cx * SourceStatistics::kCellBins;
      }
      for (std::size_t i = 0; i < width; ++i) {
        const float v = block[r * width + i];
        if (!std::isfinite(v)) {
          fail_input(source.source, "holds a NaN/Inf voxel in pages " + std::to_string(box.lo[2]) + "..");
        }
        st.min = std::min(st.min, static_cast<double>(v));
        st.max = std::max(st.max, static_cast<double>(v));
        if (integer) ++st.histogram[static_cast<std::size_t>(v)];
        if (cell_row != nullptr) {
          ++cell_row[cell_of[0][static_cast<std::size_t>(box.lo[0]) + i] * SourceStatistics::kCellBins +
                     bin_of[static_cast<std::size_t>(v)]];
        }
      }
    }
    st.voxels += static_cast<std::int64_t>(block.size());
  });
  if (share.shared()) {
    double extremes[2] = {-st.min, st.max};
    share.max(extremes);
    st.min = -extremes[0];
    st.max = extremes[1];
    sum_counts(share, std::span<std::int64_t>(&st.voxels, 1));
    sum_counts(share, st.histogram);
    sum_counts(share, st.cell_histograms);
  }
  if (!integer && st.voxels > 0 && st.max > st.min) {
    // float32: a second pass into kFloatBins equal bins over [min, max]
    st.bin_width = (st.max - st.min) / static_cast<double>(SourceStatistics::kFloatBins);
    st.histogram.assign(SourceStatistics::kFloatBins, 0);
    slabs_of(source, slab_bytes, share, [&](const VoxelBox&, std::span<const float> block) {
      for (const float v : block) {
        const auto b = static_cast<std::size_t>((static_cast<double>(v) - st.min) / st.bin_width);
        ++st.histogram[std::min(b, SourceStatistics::kFloatBins - 1)];
      }
    });
    sum_counts(share, st.histogram);
  }
  return st;
}

Normalization normalization_from(const SourceStatistics& stats, const NormalizationOptions& options,
                                 const std::string& source) {
  options.validate();
  if (stats.voxels == 0) fail_input(source, "volume is empty");
  if (!(stats.max > stats.min)) {
    std::ostringstream s;
    s << "volume is constant (every voxel is " << stats.min << "); cannot normalize";
    fail_input(source, s.str());
  }
  Normalization n;
  n.method = options.method;
  n.raw_lo = stats.min;
  n.raw_hi = stats.max;
  if (options.method == NormalizationMethod::kPercentile) {
    n.raw_lo = stats.percentile(options.percentile_lo);
    n.raw_hi = stats.percentile(options.percentile_hi);
    if (!(n.raw_hi > n.raw_lo)) {
      std::ostringstream s;
      s << "percentiles " << options.percentile_lo << " and " << options.percentile_hi << " are both " << n.raw_lo
        << "; use a wider range or `minmax`";
      fail_input(source, s.str());
    }
    // Voxels outside [lo, hi] that normalize() clips.
    if (stats.bin_width == 0) {  // 8/16-bit: exact
      for (std::size_t v = 0; v < stats.histogram.size(); ++v) {
        if (static_cast<double>(v) < n.raw_lo || static_cast<double>(v) > n.raw_hi) {
          n.clipped_voxels += stats.histogram[v];
        }
      }
    }
  }
  return n;
}

std::vector<std::int64_t> cell_counts_above(const SourceStatistics& stats, const Normalization& map, double threshold) {
  if (stats.cell_histograms.empty() || stats.bin_width != 0) {
    throw std::logic_error("cell_counts_above: no cell histograms (scan_statistics was given no CellGrid)");
  }
  constexpr std::size_t kBins = SourceStatistics::kCellBins;
  // Every stored value normalized once (as count_above); per coarse bin, the whole
  // stack's share of its voxels above the threshold (0 or 1 but where it falls).
  std::vector<float> values(stats.histogram.size());
  std::iota(values.begin(), values.end(), 0.0f);
  (void)apply_normalization(values, map);
  std::vector<double> above(kBins, 0.0), in(kBins, 0.0);
  for (std::size_t v = 0; v < values.size(); ++v) {
    const std::size_t b = stats.cell_bin(v);
    in[b] += static_cast<double>(stats.histogram[v]);
    if (values[v] > threshold) above[b] += static_cast<double>(stats.histogram[v]);
  }
  std::vector<std::int64_t> out(stats.cell_histograms.size() / kBins);
  for (std::size_t c = 0; c < out.size(); ++c) {
    double n = 0;
    for (std::size_t b = 0; b < kBins; ++b) {
      if (in[b] > 0) n += static_cast<double>(stats.cell_histograms[c * kBins + b]) * (above[b] / in[b]);
    }
    out[c] = std::llround(n);
  }
  return out;
}

std::int64_t count_above(const VolumeSource& source, const SourceStatistics& stats, const Normalization& map,
                         double threshold, std::size_t slab_bytes) {
  std::int64_t n = 0;
  if (!stats.histogram.empty() && stats.bin_width == 0) {
    // 8/16-bit: every stored value normalized once, as apply_normalization does
    std::vector<float> values(stats.histogram.size());
    std::iota(values.begin(), values.end(), 0.0f);
    (void)apply_normalization(values, map);
    for (std::size_t v = 0; v < values.size(); ++v) n += values[v] > threshold ? stats.histogram[v] : 0;
    return n;
  }
  std::vector<float> normalized;
  slabs_of(source, slab_bytes, ScanShare{}, [&](const VoxelBox&, std::span<const float> block) {
    normalized.assign(block.begin(), block.end());
    (void)apply_normalization(normalized, map);
    n += std::count_if(normalized.begin(), normalized.end(), [&](float v) { return v > threshold; });
  });
  return n;
}

}  // namespace hisnegs::io
