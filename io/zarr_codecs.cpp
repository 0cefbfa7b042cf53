// SPDX-License-Identifier: Apache-2.0
// Zarr's byte codecs through libblosc, zlib and libzstd.
#include "io/zarr_codecs.hpp"

#include <blosc.h>
#include <zlib.h>
#include <zstd.h>

#include <array>
#include <cctype>
#include <cstdlib>
#include <limits>
#include <stdexcept>

namespace hisnegs::io::zarr {
namespace {

using Bytes = std::vector<std::uint8_t>;

Bytes decode_blosc(std::span<const std::uint8_t> in, std::size_t expected) {
  std::size_t nbytes = 0;
  if (blosc_cbuffer_validate(in.data(), in.size(), &nbytes) != 0) {
    throw std::runtime_error("blosc: not a blosc stream, or truncated");
  }
  if (nbytes != expected) {
    throw std::runtime_error("blosc: holds " + std::to_string(nbytes) + " bytes, the chunk " +
                             std::to_string(expected));
  }
  // The library the stream names ("BloscLZ", "LZ4", "Snappy", "Zlib", "Zstd"); one
  // this libblosc was built without fails to decompress and is named.
  const char* library = blosc_cbuffer_complib(in.data());
  char* name = nullptr;
  char* version = nullptr;
  std::string compname = library != nullptr ? library : "";  // "Zstd" -> "zstd", "BloscLZ" -> "blosclz"
  for (char& ch : compname) ch = static_cast<char>(std::tolower(static_cast<unsigned char>(ch)));
  const bool known = !compname.empty() && blosc_get_complib_info(compname.c_str(), &name, &version) >= 0;
  std::free(name);
  std::free(version);
  if (!known) throw std::runtime_error(std::string("blosc: inner codec ") + (library ? library : "?") + " is not in this libblosc");
  Bytes out(expected);
  if (expected == 0) return out;
  const int n = blosc_decompress_ctx(in.data(), out.data(), out.size(), 1);
  if (n < 0 || static_cast<std::size_t>(n) != expected) {
    throw std::runtime_error(std::string("blosc (") + library + "): corrupt stream");
  }
  return out;
}

// zlib (RFC 1950) or gzip (RFC 1952) by windowBits; the stream must end exactly
// at `expected` bytes.
Bytes decode_deflate(std::span<const std::uint8_t> in, std::size_t expected, bool gzip) {
  if (in.size() > std::numeric_limits<uInt>::max() || expected > std::numeric_limits<uInt>::max()) {
    throw std::runtime_error("zlib: chunk over 4 GiB");
  }
  Bytes out(expected + 1);  // one spare byte: a longer stream shows as output beyond `expected`
  z_stream z{};
  if (inflateInit2(&z, gzip ? 16 + MAX_WBITS : MAX_WBITS) != Z_OK) throw std::runtime_error("zlib: cannot start");
  z.next_in = const_cast<Bytef*>(in.data());
  z.avail_in = static_cast<uInt>(in.size());
  z.next_out = out.data();
  z.avail_out = static_cast<uInt>(out.size());
  const int rc = inflate(&z, Z_FINISH);
  const std::size_t produced = out.size() - z.avail_out;
  inflateEnd(&z);
  const char* name = gzip ? "gzip" : "zlib";
  if (rc != Z_STREAM_END) throw std::runtime_error(std::string(name) + ": corrupt or truncated stream");
  if (produced != expected) {
    throw std::runtime_error(std::string(name) + ": holds " + std::to_string(produced) + " bytes, the chunk " +
                             std::to_string(expected));
  }
  out.resize(expected);
  return out;
}

Bytes decode_zstd(std::span<const std::uint8_t> in, std::size_t expected) {
  const unsigned long long stated = ZSTD_getFrameContentSize(in.data(), in.size());
  if (stated == ZSTD_CONTENTSIZE_ERROR) throw std::runtime_error("zstd: not a zstd frame");
  if (stated != ZSTD_CONTENTSIZE_UNKNOWN && stated != expected) {
    throw std::runtime_error("zstd: holds " + std::to_string(stated) + " bytes, the chunk " + std::to_string(expected));
  }
  Bytes out(expected + 1);
  const std::size_t n = ZSTD_decompress(out.data(), out.size(), in.data(), in.size());
  if (ZSTD_isError(n) != 0) throw std::runtime_error(std::string("zstd: ") + ZSTD_getErrorName(n));
  if (n != expected) {
    throw std::runtime_error("zstd: holds " + std::to_string(n) + " bytes, the chunk " + std::to_string(expected));
  }
  out.resize(expected);
  return out;
}

Bytes encode_blosc(const ByteCodec& c, std::span<const std::uint8_t> in) {
  Bytes out(in.size() + BLOSC_MAX_OVERHEAD);
  const int n = blosc_compress_ctx(c.level, c.blosc_shuffle, c.typesize, in.size(), in.data(), out.data(), out.size(),
                                   c.blosc_cname.c_str(), 0, 1);
  if (n <= 0) throw std::runtime_error("blosc: cannot compress with " + c.blosc_cname);
  out.resize(static_cast<std::size_t>(n));
  return out;
}

Bytes encode_deflate(const ByteCodec& c, std::span<const std::uint8_t> in, bool gzip) {
  z_stream z{};
  if (deflateInit2(&z, c.level, Z_DEFLATED, gzip ? 16 + MAX_WBITS : MAX_WBITS, 8, Z_DEFAULT_STRATEGY) != Z_OK) {
    throw std::runtime_error("zlib: cannot start");
  }
  Bytes out(deflateBound(&z, static_cast<uLong>(in.size())));
  z.next_in = const_cast<Bytef*>(in.data());
  z.avail_in = static_cast<uInt>(in.size());
  z.next_out = out.data();
  z.avail_out = static_cast<uInt>(out.size());
  const int rc = deflate(&z, Z_FINISH);
  out.resize(out.size() - z.avail_out);
  deflateEnd(&z);
  if (rc != Z_STREAM_END) throw std::runtime_error("zlib: cannot compress");
  return out;
}

Bytes encode_zstd(const ByteCodec& c, std::span<const std::uint8_t> in) {
  Bytes out(ZSTD_compressBound(in.size()));
  const std::size_t n = ZSTD_compress(out.data(), out.size(), in.data(), in.size(), c.level);
  if (ZSTD_isError(n) != 0) throw std::runtime_error(std::string("zstd: ") + ZSTD_getErrorName(n));
  out.resize(n);
  return out;
}

}  // namespace

std::string ByteCodec::name() const {
  switch (kind) {
    case Kind::kBlosc:
      return "blosc";
    case Kind::kZlib:
      return "zlib";
    case Kind::kGzip:
      return "gzip";
    case Kind::kZstd:
      return "zstd";
    case Kind::kCrc32c:
      return "crc32c";
  }
  return "?";
}

std::uint32_t crc32c(std::span<const std::uint8_t> bytes) {
  static const std::array<std::uint32_t, 256> table = [] {
    std::array<std::uint32_t, 256> t{};
    for (std::uint32_t i = 0; i < 256; ++i) {
      std::uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c & 1U) != 0 ? 0x82F63B78U ^ (c >> 1) : c >> 1;
      t[i] = c;
    }
    return t;
  }();
  std::uint32_t crc = 0xFFFFFFFFU;
  for (const std::uint8_t b : bytes) crc = table[(crc ^ b) & 0xFFU] ^ (crc >> 8);
  return crc ^ 0xFFFFFFFFU;
}

std::vector<std::uint8_t> decode(const ByteCodec& codec, std::span<const std::uint8_t> in, std::size_t expected) {
  switch (codec.kind) {
    case ByteCodec::Kind::kBlosc:
      return decode_blosc(in, expected);
    case ByteCodec::Kind::kZlib:
      return decode_deflate(in, expected, false);
    case ByteCodec::Kind::kGzip:
      return decode_deflate(in, expected, true);
    case ByteCodec::Kind::kZstd:
      return decode_zstd(in, expected);
    case ByteCodec::Kind::kCrc32c: {
      if (in.size() < 4 || in.size() - 4 != expected) throw std::runtime_error("crc32c: wrong length");
      const std::span<const std::uint8_t> data = in.first(in.size() - 4);
      const std::uint32_t stored = static_cast<std::uint32_t>(in[expected]) |
                                   static_cast<std::uint32_t>(in[expected + 1]) << 8 |
                                   static_cast<std::uint32_t>(in[expected + 2]) << 16 |
                                   static_cast<std::uint32_t>(in[expected + 3]) << 24;
      if (crc32c(data) != stored) throw std::runtime_error("crc32c: checksum mismatch");
      return {data.begin(), data.end()};
    }
  }
  throw std::logic_error("zarr::decode: unknown codec");
}

std::vector<std::uint8_t> encode(const ByteCodec& codec, std::span<const std::uint8_t> in) {
  switch (codec.kind) {
    case ByteCodec::Kind::kBlosc:
      return encode_blosc(codec, in);
    case ByteCodec::Kind::kZlib:
      return encode_deflate(codec, in, false);
    case ByteCodec::Kind::kGzip:
      return encode_deflate(codec, in, true);
    case ByteCodec::Kind::kZstd:
      return encode_zstd(codec, in);
    case ByteCodec::Kind::kCrc32c: {
      Bytes out(in.begin(), in.end());
      const std::uint32_t c = crc32c(in);
      for (int k = 0; k < 4; ++k) out.push_back(static_cast<std::uint8_t>(c >> (8 * k)));
      return out;
    }
  }
  throw std::logic_error("zarr::encode: unknown codec");
}

}  // namespace hisnegs::io::zarr
