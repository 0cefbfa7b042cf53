// SPDX-License-Identifier: Apache-2.0
// HDF5 stacks through the HDF5 C library: a plain 3D dataset, BigDataViewer's layout
// (an .xml beside an .h5: t00000/s00/0/cells) and Imaris (.ims: DataSet/
// ResolutionLevel 0/TimePoint 0/Channel C/Data). Header inspection, whole reads and
// region reads (hyperslabs: a region read decodes the chunks it touches, not the
// file). Does not normalize (volume.hpp); libhdf5 stays in the .cpp.
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "io/volume.hpp"

namespace hisnegs::io {

// How an HDF5 stack is chosen and interpreted (CLI --dataset, --channel,
// --timepoint, --spacing).
struct Hdf5ReadOptions {
  // Plain files: the dataset's path ("/data"); "" = the only dataset of rank 3 (or
  // of rank 4/5 with --channel/--timepoint). Ignored for BigDataViewer and Imaris.
  std::string dataset;
  // BigDataViewer: the setup (s00, s01, ...); Imaris: the channel; plain rank-4
  // (C, Z, Y, X) and rank-5 (T, C, Z, Y, X) datasets: the C index. Required when
  // there is more than one.
  std::optional<int> channel;
  // BigDataViewer t00000..; Imaris TimePoint; plain rank-5: the T index. Required
  // when there is more than one.
  std::optional<int> timepoint;
  // x, y, z voxel size in µm overriding the file (source kUser).
  std::optional<std::array<double, 3>> spacing_um;
};

enum class Hdf5Layout { kPlain, kBigDataViewer, kImaris };

// What an HDF5 stack holds, from its metadata alone.
struct Hdf5StackInfo {
  std::filesystem::path file;  // the .h5/.ims holding the data (for BigDataViewer: the one the .xml names)
  Hdf5Layout layout = Hdf5Layout::kPlain;
  std::string dataset;                // the dataset's full path
  std::vector<long long> dims;        // the dataset's extent, slowest first (as HDF5 stores it)
  long long channel_index = -1, time_index = -1;  // the fixed leading indices of a rank-4/5 dataset (-1: none)
  int nx = 0, ny = 0, nz = 0;                     // the stack (Imaris pads the dataset beyond it)
  SampleType type = SampleType::kUint16;
  bool bdv_signed16 = false;           // BigDataViewer stores uint16 as int16: read the bits as unsigned
  std::vector<long long> chunk;        // chunk extent, slowest first; empty: contiguous
  std::vector<std::string> filters;    // "deflate", "shuffle", ... (libhdf5's names)
  VoxelSpacing spacing;
  int channels = 1, timepoints = 1;    // to choose from
  // "Imaris (.ims), DataSet/ResolutionLevel 0/TimePoint 0/Channel 0/Data, uint16, chunks 32x128x128, deflate"
  [[nodiscard]] std::string describe() const;
};

// True when `path` is an HDF5 file (its signature at byte 0, 512, 1024, ...) or a
// BigDataViewer .xml (a <SpimData> document naming an hdf5 image loader).
[[nodiscard]] bool is_hdf5_stack(const std::filesystem::path& path);

// The files an HDF5 stack's values and metadata come from: `path`, then for
// BigDataViewer the .h5 an .xml names, or the .xml beside an .h5 (its voxel size).
// For caches keyed on the files' identities. Throws InputError for an .xml that
// names no file.
[[nodiscard]] std::vector<std::filesystem::path> hdf5_stack_files(const std::filesystem::path& path);

// Reads the metadata only. Throws InputError("PATH: what is wrong"), one line, for
// a file libhdf5 cannot open (not HDF5, truncated: libhdf5's innermost message is
// appended), a dataset path that does not exist or is not a dataset, a rank other
// than 3 without the indices that make it 3 (rank 4/5 need --channel / --timepoint),
// out-of-range indices, sample types other than 8/16-bit integers and float32, a
// filter libhdf5 does not have, chunks that were never written, an Imaris file
// without its size or extent attributes, a BigDataViewer .xml without its hdf5 file
// or voxel size, and a volume larger than the memory limit when read whole.
[[nodiscard]] Hdf5StackInfo inspect_hdf5_stack(const std::filesystem::path& path, const Hdf5ReadOptions& options = {});

// Raw values of the region [lo, hi) (x, y, z voxel indices, half-open, inside the
// stack) as float32, x fastest, into `out` (size = the region's voxel count).
// Thread-safe (calls into libhdf5 are serialized: Debian's build is not thread-safe).
// Throws InputError naming the file when libhdf5 fails to decode it (a corrupt or
// missing chunk, a truncated file).
void read_hdf5_region(const Hdf5StackInfo& info, const std::array<int, 3>& lo, const std::array<int, 3>& hi,
                      float* out);

// The whole stack as a Volume (raw values, normalization kNone, source = path).
[[nodiscard]] Volume read_hdf5_stack(const std::filesystem::path& path, const Hdf5ReadOptions& options = {});

// Writes `volume` as a plain HDF5 file: one dataset (Z, Y, X) of `type`, chunked
// (chunk_zyx, clipped to the stack) and gzip-compressed at `gzip_level` (0: none),
// with element_size_um = (z, y, x) spacing, atomically (temp file + rename). For
// tests, benchmarks and users who want an HDF5 copy of a TIFF stack.
struct Hdf5WriteOptions {
  std::string dataset = "/data";
  SampleType type = SampleType::kUint16;
  std::array<long long, 3> chunk_zyx{64, 64, 64};
  int gzip_level = 4;  // [0, 9]
};
void write_hdf5_stack(const std::filesystem::path& path, const Volume& volume, const Hdf5WriteOptions& options = {});

}  // namespace hisnegs::io
