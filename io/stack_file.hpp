// SPDX-License-Identifier: Apache-2.0
// Any stack hisnegs reads, by what the file is (not its name): TIFF/BigTIFF
// (tiff_stack.hpp), HDF5 (hdf5_stack.hpp: plain, BigDataViewer .xml/.h5, Imaris
// .ims) or an OME-Zarr / Zarr folder (zarr_stack.hpp). Every command that reads a
// stack goes through here.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "io/hdf5_stack.hpp"
#include "io/tiff_stack.hpp"
#include "io/volume.hpp"
#include "io/zarr_stack.hpp"

namespace hisnegs::io {

// How a stack file is chosen and interpreted, whatever its format (CLI --channel,
// --timepoint, --dataset, --spacing). tiff.channel and tiff.spacing_um serve both.
struct StackReadOptions {
  TiffReadOptions tiff;
  std::string dataset;           // HDF5: the dataset's path ("" = the only stack)
  std::optional<int> timepoint;  // HDF5 and OME-Zarr time series
  int level = 0;                 // OME-Zarr: the multiscale level
  [[nodiscard]] Hdf5ReadOptions hdf5() const;
  [[nodiscard]] ZarrReadOptions zarr() const;
};

// A stack's header: what inspect_tiff_stack / inspect_hdf5_stack found, in common.
struct StackHeader {
  int nx = 0, ny = 0, nz = 0;
  SampleType type = SampleType::kUint8;
  VoxelSpacing spacing;
  int channels = 1;
  std::string format;  // "TIFF (BigTIFF), 60 pages, uint8, LZW, striped" / Hdf5StackInfo::describe()
};

// Checks that `path` names something a stack can be: a Zarr folder or a regular
// file (throws InputError as require_regular_file otherwise; the reader checks the rest).
void require_stack_path(const std::filesystem::path& path);

// The header an HDF5 or Zarr reader inspected, as inspect_stack gives it.
[[nodiscard]] StackHeader header_of(const Hdf5StackInfo& info);
[[nodiscard]] StackHeader header_of(const ZarrStackInfo& info);
// A Zarr stack as every stack command reads it: --dataset refused, then
// inspect_zarr_stack with the options' level, channel, time point and spacing.
[[nodiscard]] ZarrStackInfo inspect_zarr_for(const std::filesystem::path& path, const StackReadOptions& options);
// --level refused (one line) for a stack of one level (TIFF, HDF5).
void refuse_level(const std::filesystem::path& path, const StackReadOptions& options);

[[nodiscard]] StackHeader inspect_stack(const std::filesystem::path& path, const StackReadOptions& options = {});

// The whole stack (raw values, normalization kNone). A TIFF refuses --dataset and
// --timepoint (one line naming them).
[[nodiscard]] Volume read_stack(const std::filesystem::path& path, const StackReadOptions& options = {});

// Every file behind a stack, the one named first: a BigDataViewer stack's .xml and
// the .h5 it names (or an .h5 and the .xml beside it that gives its voxel size);
// any other stack is its one file. What an input is, for output guards and
// fingerprints. Never throws: a malformed BigDataViewer .xml is its one file (its
// reader says what is wrong with it).
[[nodiscard]] std::vector<std::filesystem::path> stack_files(const std::filesystem::path& path);

// What a stack is, as every fingerprint and input guard sees it: the path it was
// named by and every file behind it (stack_files). One definition for the run
// stages' fingerprints, the bricked fit's brick folder, the statistics cache and
// the guards that refuse an output that is any file of an input.
struct StackIdentity {
  std::filesystem::path named;
  std::vector<std::filesystem::path> files;  // the one named first; empty for a stack in memory
  // Size, modification time (ns) and device:inode of each file, "missing" for one
  // that is gone, without the path: an atomic rewrite (a new inode) or a change of
  // any file behind the stack (a BigDataViewer .h5 behind its .xml) gives a new
  // value; moving the folder does not. Throws std::filesystem::filesystem_error
  // when the named file cannot be stat'ed.
  [[nodiscard]] std::string content() const;
  // Whether `path` is one of the files (the same file: io::same_file), or lies
  // inside a folder stack (OME-Zarr) among them.
  [[nodiscard]] bool holds(const std::filesystem::path& path) const;
};
[[nodiscard]] StackIdentity stack_identity(const std::filesystem::path& path);

}  // namespace hisnegs::io
