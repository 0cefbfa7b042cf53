// SPDX-License-Identifier: Apache-2.0
// The compact checkpoint (docs/file-formats.md "Compact checkpoint", `.hgs`): the
// mixture quantized per attribute into byte-plane columns, compressed with zstd,
// after a small header with the metadata; encoding, checked decoding and the error
// bounds of the quantization. Does not know PLY (gmf/core/checkpoint.hpp) nor the CLI.
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

#include "gmf/core/checkpoint.hpp"
#include "gmf/core/gaussian_mixture.hpp"

namespace hisnegs::gmf {

// The compact format version this build reads and writes (the header's `version`;
// independent of CheckpointMeta::format_version, which the metadata lines carry).
// Version 2 added the CRC-32 of the whole file at its end; version 1 files (no
// checksum) are still read.
inline constexpr std::uint32_t kCompactFormatVersion = 2;

// The first 8 bytes of every compact checkpoint. As PNG's signature: the high first
// byte catches 7-bit transfers and tells it from a PLY ("ply"), CR LF and LF catch
// line-ending conversion, ^Z stops a DOS `type`.
inline constexpr std::array<char, 8> kCompactMagic = {'\x89', 'H', 'G', 'S', '\r', '\n', '\x1a', '\n'};

// Bit depths of the quantized columns (stored in the header, so a reader needs no
// options) and the entropy coder's effort. Defaults: docs/benchmarks.md "Compact
// checkpoint" (op1's trained model, evaluation PSNR within 0.05 dB of the PLY).
struct CompactOptions {
  // Bits per centre coordinate, uniform over the model's bounding box per axis;
  // 8..21 (3 × bits ≤ 63: the Morton code is one uint64).
  int position_bits = 16;
  // Bits per log-scale, uniform over the model's range of that axis' log-scale; 4..16.
  int scale_bits = 8;
  // Bits per smallest-three quaternion component, uniform over [-1/√2, 1/√2]; 4..15.
  int rotation_bits = 10;
  // Bits of the intensity a = sigmoid(intensity_logit): 2^bits levels evenly
  // spaced over [0, 1], both ends included; 4..16.
  int intensity_bits = 8;
  // zstd compression level, 1..22 (19 and up: slow to write, as fast to read).
  int zstd_level = 19;

  // Throws io::InputError naming the field, its value and the valid range.
  void validate() const;
};

// What a compact file's header says (checked as read_compact_header describes).
struct CompactHeader {
  std::uint32_t version = kCompactFormatVersion;
  std::uint64_t count = 0;  // K, the number of Gaussians
  CompactOptions bits;      // its *_bits fields; zstd_level is not stored (left at its default)
  // The model's box (min / max of the centres per axis) and log-scale ranges per
  // axis, as float32 values of the model: both ends decode exactly.
  std::array<float, 3> position_lo{}, position_hi{};
  std::array<float, 3> log_scale_lo{}, log_scale_hi{};
  std::uint64_t metadata_bytes = 0;  // of the metadata text
  std::uint64_t payload_bytes = 0;   // of the zstd frame
  std::uint64_t file_bytes = 0;      // the whole file
  bool checksummed = false;          // a CRC-32 covers the file (version >= 2) and matched
};

// The largest difference between a Gaussian and its decoded copy that a file with
// this header allows (docs/file-formats.md "Bounds"). Float32 rounding of the decoded
// value (half an ulp of it) comes on top of the position and log-scale bounds.
struct CompactBounds {
  std::array<double, 3> position{};   // |x̂ − x| per axis, world units: half a step of the box
  std::array<double, 3> log_scale{};  // |ŝ − s| per axis (log-scales): half a step of the range
  // ‖q̂ − q‖ for q = rotation / |rotation| with the sign of q̂ (q and −q are one
  // rotation); q̂ is unit. The rotation angle between them is below 2.1 × this.
  double rotation = 0.0;
  // |sigmoid(ℓ̂) − sigmoid(ℓ)|: half a step, 1 / (2 (2^bits − 1)), + 1e-7 (the ends
  // a = 0 and 1 decode to 1e-7 and 1 − 1e-7). The logit itself is not bounded: a
  // saturated ℓ = 24 decodes to 16.12.
  double intensity = 0.0;
};

[[nodiscard]] CompactBounds compact_bounds(const CompactHeader& header);

// The compact file of a mixture and its metadata. The Gaussians are stored in the
// Morton (Z-curve) order of their quantized centres, ties in input order, not in
// input order: decoding gives the same set in that order. `order`, if given, gets
// for each stored Gaussian i the index of the input Gaussian it holds. Throws
// io::InputError for options out of range (CompactOptions::validate) and
// std::invalid_argument as checkpoint_to_ply does (a non-finite parameter, an
// all-zero quaternion, metadata it could not read back).
[[nodiscard]] std::string encode_compact_checkpoint(const GaussianMixture& mixture, const CheckpointMeta& meta,
                                                    const CompactOptions& options = {},
                                                    std::vector<std::size_t>* order = nullptr);

// CRC-32 (zlib's: ISO 3309 / ITU-T V.42, the one of gzip and PNG) of `bytes`: what
// a compact file (version >= 2) and a hierarchy file end with.
[[nodiscard]] std::uint32_t crc32_of(std::string_view bytes);
// Whether `bytes` starts with kCompactMagic.
[[nodiscard]] bool has_compact_magic(std::string_view bytes);

// Reads and checks the header of the compact file `bytes` (the whole file) against
// its size, before anything is allocated: magic, version, the CRC-32 of the whole
// file (version >= 2) before any other field, bit depths in range, finite boxes with
// lo ≤ hi, metadata size, payload size equal to the rest of the file, and K × bytes
// per Gaussian at most 1024 times the payload (or 1 MiB). Throws io::InputError,
// one line "SOURCE: compact checkpoint: problem".
[[nodiscard]] CompactHeader read_compact_header(std::string_view bytes, const std::filesystem::path& source);

// Decodes a whole compact file. Beyond read_compact_header: the metadata lines parse
// as a PLY checkpoint's do; the payload is one zstd frame that records its content
// size, which must be K × (bytes per Gaussian) (checked against the memory limit
// before allocating); every code fits its bit depth; every decoded value is finite.
// Throws io::InputError, one line "SOURCE: ...", for any problem.
[[nodiscard]] Checkpoint decode_compact_checkpoint(std::string_view bytes, const std::filesystem::path& source);

// Writes the compact file atomically (temp file + rename); returns its header.
// Throws std::invalid_argument "PATH: cannot save checkpoint: ..." as
// encode_compact_checkpoint does (nothing is written then), io::InputError /
// io::WriteError if the file cannot be written.
CompactHeader save_compact_checkpoint(const std::filesystem::path& path, const GaussianMixture& mixture,
                                      const CheckpointMeta& meta, const CompactOptions& options = {});

// Reads a compact file (load_checkpoint calls this for files with the magic).
// Throws io::InputError naming the file.
[[nodiscard]] Checkpoint load_compact_checkpoint(const std::filesystem::path& path);

}  // namespace hisnegs::gmf
