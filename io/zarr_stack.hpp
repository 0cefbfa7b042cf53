// SPDX-License-Identifier: Apache-2.0
// OME-Zarr stacks: a folder `X.ome.zarr` (an OME-NGFF multiscale group: v0.4 on
// Zarr v2, v0.5 on Zarr v3) or one Zarr array folder. Zarr v2 (.zarray; `.` or `/`
// chunk keys; compressors blosc, zlib, gzip, zstd or none; C order) and v3
// (zarr.json; codecs bytes, transpose, blosc, gzip, zstd, crc32c and
// sharding_indexed); uint8, uint16, int16 and float32, either byte order. Axes
// t, c, z, y, x (any subset OME allows) with their units; the level's scale gives
// the spacing in µm. A region read decodes only the chunks (or a shard's inner
// chunks) the box meets; chunks never written read as the fill value. Writing: a
// multiscale OME-Zarr v0.4 pyramid (Zarr v2, blosc-zstd). Does not normalize.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "io/volume.hpp"

namespace hisnegs::io {

struct ZarrReadOptions {
  int level = 0;                   // the multiscale level (0: full resolution)
  std::optional<int> channel;      // the c index, required when there are several
  std::optional<int> timepoint;    // the t index, required when there are several
  std::optional<std::array<double, 3>> spacing_um;  // x, y, z overriding the file
};

namespace zarr {
struct Array;  // the decoding plan of one array (zarr_stack.cpp)
}

// One level of a multiscale pyramid, as `info` shows it.
struct ZarrLevel {
  std::string path;                 // relative to the group
  std::vector<long long> shape;     // slowest first
  std::vector<long long> chunks;    // the chunk (v3 sharded: the inner chunk), slowest first
  std::string codecs;               // "blosc(zstd)", "sharding(512x512x512; blosc(zstd))", "none"
  std::array<double, 3> scale_um{1, 1, 1};  // x, y, z
};

struct ZarrStackInfo {
  std::filesystem::path named;   // the folder named
  std::filesystem::path array;   // the array folder read
  int zarr_format = 2;
  std::string ome_version;       // "0.4", "0.5"; "" for a bare array
  std::string axes;              // one letter per array dimension, slowest first: "tczyx", "zyx"
  std::string dtype;             // "uint16", "int16", ...
  int nx = 0, ny = 0, nz = 0;
  SampleType type = SampleType::kUint16;  // int16 reads as kFloat32 (signed values kept)
  long long channel_index = -1, time_index = -1;
  int channels = 1, timepoints = 1;
  int level = 0;
  std::vector<ZarrLevel> pyramid;  // every level (a bare array: itself)
  VoxelSpacing spacing;
  std::shared_ptr<const zarr::Array> plan;
  // "OME-Zarr v0.4 (Zarr v2), level 0 of 3, uint16, chunks 64x64x64, blosc(zstd)"
  [[nodiscard]] std::string describe() const;
};

// True when `path` is a folder holding Zarr metadata (.zarray, .zgroup, .zattrs or
// zarr.json).
[[nodiscard]] bool is_zarr_stack(const std::filesystem::path& path);

// Reads the metadata only. Throws InputError("PATH: what is wrong"), one line, for
// metadata that is not valid JSON or misses a field, a level, channel or time point
// out of range (or not chosen when there are several), types, codecs, filters or an
// F order hisnegs does not read, a dataset path that leaves the folder, and sizes
// out of bounds.
[[nodiscard]] ZarrStackInfo inspect_zarr_stack(const std::filesystem::path& path, const ZarrReadOptions& options = {});

// Raw values of [lo, hi) (x, y, z, inside the stack) as float32, x fastest. Decodes
// only the chunks the box meets; thread-safe. Throws InputError naming the chunk's
// file when it cannot be decoded.
void read_zarr_region(const ZarrStackInfo& info, const std::array<int, 3>& lo, const std::array<int, 3>& hi,
                      float* out);

// The files that make the stack what it is, the folder named first: its metadata
// files and the array folder read (whose chunk files StackIdentity walks).
[[nodiscard]] std::vector<std::filesystem::path> zarr_stack_files(const std::filesystem::path& path);

// Writes `volume` as an OME-Zarr v0.4 multiscale pyramid (Zarr v2, blosc-zstd with
// byte shuffle, chunks of chunk_edge³, levels halved in x and y, and in z while
// that keeps voxels nearer cubic, by the mean of each block, down to `min_edge`),
// with the volume's spacing, into a temp folder renamed into place. Sample type:
// `type` (float32 values kept, uint8/uint16 rounded after clamping).
struct ZarrWriteOptions {
  SampleType type = SampleType::kFloat32;
  int chunk_edge = 64;
  int min_edge = 64;
  int max_levels = 8;
  int zstd_level = 5;
};
void write_ome_zarr(const std::filesystem::path& path, const Volume& volume, const ZarrWriteOptions& options = {});

}  // namespace hisnegs::io
