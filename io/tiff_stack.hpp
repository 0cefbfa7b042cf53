// SPDX-License-Identifier: Apache-2.0
// Multi-page TIFF stacks (pages = Z) <-> io::Volume: reading, header-only inspection, atomic ImageJ-style writing.
// Does not normalize (volume.hpp) or parse metadata text (detail/tiff_metadata.hpp); libtiff stays in the .cpp.
#pragma once

#include <array>
#include <filesystem>
#include <memory>
#include <optional>
#include <span>
#include <string>

#include "io/volume.hpp"

namespace hisnegs::io {

// How read_tiff_stack / inspect_tiff_stack interpret a file (CLI --channel, --spacing).
struct TiffReadOptions {
  // 0-based channel for multi-channel files (SamplesPerPixel > 1, ImageJ
  // channels=, OME SizeC); required when the file has more than one channel.
  std::optional<int> channel = std::nullopt;
  // x, y, z voxel size in µm overriding the file's metadata (source kUser);
  // each must be finite and > 0.
  std::optional<std::array<double, 3>> spacing_um = std::nullopt;
  // Throws InputError naming the field, its value and the rule broken.
  void validate() const;
};

// Reads a whole stack V[z][y][x]. Values are the raw samples as float32 (not
// normalized: normalization.method = kNone), stored_as = the file's sample type,
// source = path. Spacing and its per-axis source follow CONVENTIONS precedence:
// options.spacing_um > OME-XML PhysicalSize* > ImageJ (`spacing=` for z;
// X/YResolution in pixels per the description's `unit=` for x, y) >
// X/YResolution with ResolutionUnit = centimeter > 1 µm. ResolutionUnit inch
// without an ImageJ unit is display DPI and ignored.
// Channels: SamplesPerPixel > 1, ImageJ hyperstacks (`channels=`, page =
// (t*Z + z)*C + c) and OME-XML SizeC (page order from DimensionOrder; the first
// <Pixels> image only, starting at page 0; TiffData elements are not consulted).
// Throws InputError("PATH: what is wrong"), one line, for every unusable file:
// not a TIFF or truncated (libtiff's last error is appended), fewer than 2
// pages, unsupported sample formats, pages of differing shape or type, several
// channels without options.channel, several time points, NaN/Inf voxels, or a
// volume larger than the memory limit (checked before allocating: /proc/meminfo
// MemAvailable, or the environment variable HISNEGS_MAX_ALLOC_GB in GiB).
[[nodiscard]] Volume read_tiff_stack(const std::filesystem::path& path, const TiffReadOptions& options = {});

// Where each page's directory (IFD) starts, with the stack's layout: one walk of the
// directory chain, checking every page as read_tiff_stack does, made once for many
// region reads. Throws InputError as read_tiff_stack does.
class TiffPageIndex;
[[nodiscard]] std::shared_ptr<const TiffPageIndex> index_tiff_pages(const std::filesystem::path& path,
                                                                    const TiffReadOptions& options = {});

// The voxels [lo, hi) (x, y, z) of the stack into `out` (x fastest), with every
// check read_tiff_stack makes, decoding only the pages, strips and tiles the box
// meets into one reused page buffer: memory is one page plus `out`. Without `index`
// libtiff walks the directory chain from page 0 to the box's last page; with the
// file's index (index_tiff_pages, same options) it goes to the box's pages directly,
// so the cost of a read does not grow with its depth in the stack.
// std::invalid_argument for a box that is empty or outside the stack.
void read_tiff_region(const std::filesystem::path& path, const TiffReadOptions& options, const std::array<int, 3>& lo,
                      const std::array<int, 3>& hi, float* out, const TiffPageIndex* index = nullptr);

// How write_tiff_stack stores a stack.
struct TiffWriteOptions {
  // Sample type on disk. kUint8/kUint16 require every value to be an integer in
  // range (InputError otherwise: values are never clamped or rounded).
  SampleType type = SampleType::kFloat32;
  // x, y, z voxel size in µm (finite, > 0), written as ImageJ metadata:
  // X/YResolution = 1/s pixels per µm, `unit=um`, `spacing=` z. X/Y round-trip
  // through TIFF's float rationals (about 7 significant digits), z exactly.
  std::optional<std::array<double, 3>> spacing_um = std::nullopt;
  // Adobe deflate compression; integer types add the horizontal predictor,
  // float32 none (ImageJ cannot read the floating-point predictor).
  bool deflate = false;
  // Throws InputError naming the field, its value and the rule broken.
  void validate() const;
};

// Writes nz pages of ny rows × nx columns from `voxels` (x fastest, size
// nx*ny*nz, nx, ny, nz >= 1) atomically (temp file + rename). MINISBLACK, one
// sample per pixel, strips of at most ~8 MiB (one per page for usual sizes),
// BigTIFF when the uncompressed data exceed ~3.5 GiB, and an ImageJ
// description ("ImageJ=1.11a\nimages=N\nslices=N\n[unit=um\nspacing=z\n]min=..\nmax=..\n")
// so ImageJ/Fiji/tifffile open it as a stack. Throws InputError naming the path
// and the first offending voxel for NaN/Inf values (any type) or values that do
// not fit an integer type (checked before anything is created); std::invalid_argument
// if voxels.size() != nx*ny*nz; std::runtime_error naming the path if writing fails
// (disk full, ...). The target is untouched and no temporary file remains on any throw.
void write_tiff_stack(const std::filesystem::path& path, std::span<const float> voxels, int nx, int ny, int nz,
                      const TiffWriteOptions& options = {});

// Writes `volume` as above. When options.spacing_um is empty the volume's
// spacing is written, unless all three axes are kDefault (unknown spacing stays
// unknown: nothing is written, so reading back gives kDefault again).
void write_tiff_stack(const std::filesystem::path& path, const Volume& volume, const TiffWriteOptions& options);

// What a stack holds, from its tags only (no pixel data is decoded).
struct TiffStackInfo {
  int nx = 0, ny = 0, nz = 0;  // X (columns), Y (rows), Z (slices of one channel)
  int channels = 1;            // channels to choose from (samples × page channels)
  SampleType type = SampleType::kUint8;
  VoxelSpacing spacing;     // as read_tiff_stack would report it
  std::string compression;  // libtiff codec name of page 0 ("None", "LZW", "AdobeDeflate", ...)
  bool tiled = false;       // page 0 is tiled
  bool bigtiff = false;     // BigTIFF (64-bit offsets)
  int pages = 0;            // IFDs in the file
};

// Reads only the header: nz, channels and spacing as read_tiff_stack would
// resolve them. Unlike read_tiff_stack it accepts a single page and does not
// require options.channel (info reports the channel count); an out-of-range
// options.channel, unsupported sample formats, time series and non-TIFF files
// throw InputError as read_tiff_stack does.
[[nodiscard]] TiffStackInfo inspect_tiff_stack(const std::filesystem::path& path, const TiffReadOptions& options = {});

}  // namespace hisnegs::io
