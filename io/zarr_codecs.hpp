// SPDX-License-Identifier: Apache-2.0
// The byte codecs a Zarr chunk goes through, by the libraries that implement them:
// blosc (libblosc: every inner codec and shuffle mode it was built with), zlib and
// gzip (zlib), zstd (libzstd), and the CRC-32C checksum a v3 shard index carries.
// Decoding knows the size the result must have (the chunk's) and refuses any
// other: a crafted stream cannot size an allocation.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace hisnegs::io::zarr {

// A bytes-to-bytes codec of a chunk, as the array's metadata names it.
struct ByteCodec {
  enum class Kind { kBlosc, kZlib, kGzip, kZstd, kCrc32c };
  Kind kind = Kind::kZlib;
  // Encoding only (decoding reads everything from the stream):
  int level = 5;              // zlib/gzip 0..9, zstd 1..22, blosc clevel 0..9
  std::string blosc_cname = "zstd";
  int blosc_shuffle = 1;      // 0 none, 1 byte, 2 bit
  std::size_t typesize = 1;   // blosc's shuffle element size
  [[nodiscard]] std::string name() const;  // "blosc", "zlib", "gzip", "zstd", "crc32c"
};

// Decodes `in` into exactly `expected` bytes (crc32c: checks and strips its 4
// bytes, `expected` is then in.size() - 4). Throws std::runtime_error("what is
// wrong") for a stream that is corrupt, of another size, or of a blosc codec this
// libblosc was built without; the caller names the file.
[[nodiscard]] std::vector<std::uint8_t> decode(const ByteCodec& codec, std::span<const std::uint8_t> in,
                                               std::size_t expected);
[[nodiscard]] std::vector<std::uint8_t> encode(const ByteCodec& codec, std::span<const std::uint8_t> in);

// CRC-32C (Castagnoli), as Zarr v3's crc32c codec: little-endian after the data.
[[nodiscard]] std::uint32_t crc32c(std::span<const std::uint8_t> bytes);

}  // namespace hisnegs::io::zarr
