// SPDX-License-Identifier: Apache-2.0
// The compact checkpoint: quantization of each attribute, the Morton order, byte
// planes, the zstd stage, the header, and the checks of decoding. The metadata lines
// are the PLY checkpoint's (gmf/core/checkpoint.hpp); no PLY here.
#include "gmf/core/compact_checkpoint.hpp"

#include <zlib.h>
#include <zstd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <new>
#include <numeric>
#include <stdexcept>

#include "gmf/core/gaussian_math.hpp"
#include "io/atomic_file.hpp"
#include "io/binary_io.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"

namespace hisnegs::gmf {
namespace fs = std::filesystem;

// CRC-32 (zlib's: ISO 3309 / ITU-T V.42, the one of gzip and PNG) of `bytes`: it
// catches every error of up to 3 bits and every burst of up to 32 bits in a file
// of this size, and all but 2^-32 of the rest.
std::uint32_t crc32_of(std::string_view bytes) {
  uLong crc = ::crc32(0L, Z_NULL, 0);
  for (std::size_t at = 0; at < bytes.size();) {  // zlib takes uInt lengths
    const auto n = static_cast<uInt>(std::min<std::size_t>(bytes.size() - at, std::size_t{1} << 30));
    crc = ::crc32(crc, reinterpret_cast<const Bytef*>(bytes.data() + at), n);
    at += n;
  }
  return static_cast<std::uint32_t>(crc);
}

namespace {

// Header layout (docs/file-formats.md): magic 8, version u32, K u64, four u8 bit
// depths, position box 6 × f32, log-scale ranges 6 × f32, metadata size u64, the
// metadata, payload size u64, the payload.
constexpr std::size_t kFixedHeaderBytes = 8 + 4 + 8 + 4 + 24 + 24 + 8 + 8;  // with no metadata
constexpr std::uint64_t kMaxMetadataBytes = std::uint64_t{1} << 20;
constexpr std::size_t kMaxMetadataLineBytes = 64 * 1024 - 8;  // a PLY header line, less "comment "
// Version 2 ends with the CRC-32 of every byte before it (the first version that has one).
constexpr std::uint32_t kFirstChecksummedVersion = 2;
constexpr std::size_t kChecksumBytes = 4;
// How many times its payload a file's K × B raw columns may be. zstd alone allows
// ~43,690 (a 3-byte RLE block yields 128 KiB), so a 2.5 KB file could make a reader
// allocate hundreds of MB. Models compress far less (docs/benchmarks.md "Compact
// checkpoint": trained op1 1.2:1; a regular grid with intensities from a volume
// 8.7:1; a constant-intensity 40³ grid 22:1, 64³ 449:1), so 1024:1 refuses only a
// degenerate model (e.g. one Gaussian repeated) while bounding what a file can
// claim. Below kFreeRawBytes any ratio is accepted: tiny models cost nothing.
constexpr std::uint64_t kMaxCompressionRatio = 1024;
constexpr std::uint64_t kFreeRawBytes = std::uint64_t{1} << 20;
constexpr double kHalfSqrt2 = 0.70710678118654752440;  // 1/√2: the smallest-three range
// The intensity levels include a = 0 and a = 1 (a fifth of a trained model's
// Gaussians are saturated, ℓ > 6: they decode as bright as they were, not half a
// step darker on every bright pixel). Their logits would be infinite, so the ends
// decode to a = 1e-7 and 1 − 1e-7 (ℓ̂ = ∓16.12), within 1e-7 of the level.
constexpr double kIntensityEnd = 1e-7;

constexpr const char* kWhat = "compact checkpoint: ";

struct Range {
  int lo, hi;
};
constexpr Range kPositionBits{8, 21}, kScaleBits{4, 16}, kRotationBits{4, 15}, kIntensityBits{4, 16}, kZstdLevel{1, 22};

void check_range(const char* field, int value, Range r) {
  if (value < r.lo || value > r.hi) {
    throw io::InputError(std::string(field) + " = " + std::to_string(value) + ": must be in " + std::to_string(r.lo) +
                         ".." + std::to_string(r.hi));
  }
}

std::size_t bytes_for(int bits) { return static_cast<std::size_t>(bits + 7) / 8; }

// Byte planes per column and per Gaussian (the payload is K × per_gaussian bytes).
struct Layout {
  std::size_t position, scale, rotation, intensity;  // planes of one column each
  [[nodiscard]] std::size_t per_gaussian() const { return position + 3 * scale + rotation + intensity; }
};

Layout layout_of(const CompactOptions& bits) {
  return {bytes_for(3 * bits.position_bits), bytes_for(bits.scale_bits), bytes_for(2 + 3 * bits.rotation_bits),
          bytes_for(bits.intensity_bits)};
}

std::uint64_t max_code(int bits) { return (std::uint64_t{1} << bits) - 1; }

// Uniform quantization of v in [lo, hi] to 0..m, rounding to the nearest level.
std::uint64_t quantize(double v, double lo, double hi, std::uint64_t m) {
  if (!(hi > lo)) return 0;
  const double t = std::nearbyint((v - lo) / (hi - lo) * static_cast<double>(m));
  return static_cast<std::uint64_t>(std::clamp(t, 0.0, static_cast<double>(m)));
}

double dequantize(std::uint64_t c, double lo, double hi, std::uint64_t m) {
  if (!(hi > lo)) return lo;
  return lo + (hi - lo) * (static_cast<double>(c) / static_cast<double>(m));
}

// Morton code: bit b of x, y, z goes to bit 3b, 3b + 1, 3b + 2 (21 bits each at most).
std::uint64_t spread3(std::uint64_t v) {
  v &= 0x1fffff;
  v = (v | v << 32) & 0x1f00000000ffffULL;
  v = (v | v << 16) & 0x1f0000ff0000ffULL;
  v = (v | v << 8) & 0x100f00f00f00f00fULL;
  v = (v | v << 4) & 0x10c30c30c30c30c3ULL;
  v = (v | v << 2) & 0x1249249249249249ULL;
  return v;
}

std::uint64_t compact3(std::uint64_t v) {
  v &= 0x1249249249249249ULL;
  v = (v ^ (v >> 2)) & 0x10c30c30c30c30c3ULL;
  v = (v ^ (v >> 4)) & 0x100f00f00f00f00fULL;
  v = (v ^ (v >> 8)) & 0x1f0000ff0000ffULL;
  v = (v ^ (v >> 16)) & 0x1f00000000ffffULL;
  v = (v ^ (v >> 32)) & 0x1fffff;
  return v;
}


// One column of K values, `planes` bytes each, least significant plane first:
// value k's byte b is at column[b × K + k]. Planes of like bytes compress far
// better than interleaved values (the high bytes of small numbers are all zero).
class Planes {
 public:
  Planes(char* column, std::size_t count, std::size_t planes) : column_(column), count_(count), planes_(planes) {}
  void put(std::size_t k, std::uint64_t value) const {
    for (std::size_t b = 0; b < planes_; ++b) column_[b * count_ + k] = static_cast<char>((value >> (8 * b)) & 0xff);
  }
  [[nodiscard]] std::uint64_t get(std::size_t k) const {
    std::uint64_t v = 0;
    for (std::size_t b = 0; b < planes_; ++b) {
      v |= static_cast<std::uint64_t>(static_cast<unsigned char>(column_[b * count_ + k])) << (8 * b);
    }
    return v;
  }

 private:
  char* column_;
  std::size_t count_, planes_;
};

// The columns of a payload in file order: position gaps, log-scale 0, 1, 2,
// rotation, intensity.
struct Columns {
  Planes position, scale0, scale1, scale2, rotation, intensity;
  Columns(char* raw, std::size_t count, const Layout& l)
      : position(raw, count, l.position),
        scale0(raw + count * l.position, count, l.scale),
        scale1(raw + count * (l.position + l.scale), count, l.scale),
        scale2(raw + count * (l.position + 2 * l.scale), count, l.scale),
        rotation(raw + count * (l.position + 3 * l.scale), count, l.rotation),
        intensity(raw + count * (l.position + 3 * l.scale + l.rotation), count, l.intensity) {}
  [[nodiscard]] const Planes& scale(int d) const { return d == 0 ? scale0 : (d == 1 ? scale1 : scale2); }
};

// What is wrong with a metadata line, or "" if nothing. The rules are the PLY
// reader's for a header comment (io/ply.cpp: printable but for tabs, at most
// 64 KiB with "comment "), so a compact file's metadata can always be saved as a
// PLY and read back, and the other way round.
std::string metadata_line_problem(std::string_view line) {
  if (line.size() > kMaxMetadataLineBytes) {
    return "is longer than " + std::to_string(kMaxMetadataLineBytes) + " bytes";
  }
  for (char c : line) {
    const auto u = static_cast<unsigned char>(c);
    if ((u < 0x20 && c != '\t') || u == 0x7f) return "holds a control character";
  }
  if (!line.starts_with("hisnegs ")) return "is not 'hisnegs KEY VALUE'";
  return "";
}

// The metadata text of `meta`: its lines joined by line feeds. Throws
// std::invalid_argument for metadata a reader would refuse.
std::string metadata_text(const CheckpointMeta& meta) {
  const std::vector<std::string> lines = checkpoint_comments(meta);
  std::string text;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    if (const std::string problem = metadata_line_problem(lines[i]); !problem.empty()) {
      throw std::invalid_argument("checkpoint metadata line '" + io::printable(lines[i], 60) + "' " + problem);
    }
    if (i) text += '\n';
    text += lines[i];
  }
  if (text.size() > kMaxMetadataBytes) {
    throw std::invalid_argument("checkpoint metadata of " + std::to_string(text.size()) + " bytes is more than the " +
                                std::to_string(kMaxMetadataBytes) + " a compact checkpoint holds");
  }
  return text;
}

}  // namespace

void CompactOptions::validate() const {
  check_range("position_bits", position_bits, kPositionBits);
  check_range("scale_bits", scale_bits, kScaleBits);
  check_range("rotation_bits", rotation_bits, kRotationBits);
  check_range("intensity_bits", intensity_bits, kIntensityBits);
  check_range("zstd_level", zstd_level, kZstdLevel);
}

CompactBounds compact_bounds(const CompactHeader& header) {
  CompactBounds b;
  const auto half_step = [](double lo, double hi, int bits) {
    return hi > lo ? 0.5 * (hi - lo) / static_cast<double>(max_code(bits)) : 0.0;
  };
  for (int d = 0; d < 3; ++d) {
    b.position[d] = half_step(header.position_lo[d], header.position_hi[d], header.bits.position_bits);
    b.log_scale[d] = half_step(header.log_scale_lo[d], header.log_scale_hi[d], header.bits.scale_bits);
  }
  // Each of the three small components v is within δ (half a step) of the file's.
  // The largest, q_i = sqrt(1 − Σv²) ≥ 1/2, then moves by at most
  // |Σv² − Σv̂²| / q_i ≤ δ (2 Σ|v| + 3δ) / q_i ≤ δ (6 + 6δ), because
  // Σ|v| ≤ √3 sqrt(1 − q_i²) ≤ 3 q_i when q_i ≥ 1/2. Hence ‖q̂ − q‖ ≤ δ sqrt(3 + (6 + 6δ)²);
  // q̂ is unit as decoded (Σv̂² < 1 for every allowed bit depth).
  const double delta = kHalfSqrt2 / static_cast<double>(max_code(header.bits.rotation_bits));
  b.rotation = delta * std::sqrt(3.0 + (6.0 + 6.0 * delta) * (6.0 + 6.0 * delta));
  b.intensity = 0.5 / static_cast<double>(max_code(header.bits.intensity_bits)) + kIntensityEnd;
  return b;
}

bool has_compact_magic(std::string_view bytes) {
  return bytes.size() >= kCompactMagic.size() &&
         std::memcmp(bytes.data(), kCompactMagic.data(), kCompactMagic.size()) == 0;
}

namespace {

// The header of `mixture`'s file: count, bits and the boxes of centres and log-scales.
CompactHeader header_of(const GaussianMixture& mixture, const CompactOptions& options) {
  CompactHeader h;
  h.count = mixture.size();
  h.bits = options;
  if (!mixture.empty()) {
    h.position_lo = h.position_hi = mixture[0].mean;
    h.log_scale_lo = h.log_scale_hi = mixture[0].log_scale;
  }
  for (const GaussianParams& g : mixture) {
    for (int d = 0; d < 3; ++d) {
      h.position_lo[d] = std::min(h.position_lo[d], g.mean[d]);
      h.position_hi[d] = std::max(h.position_hi[d], g.mean[d]);
      h.log_scale_lo[d] = std::min(h.log_scale_lo[d], g.log_scale[d]);
      h.log_scale_hi[d] = std::max(h.log_scale_hi[d], g.log_scale[d]);
    }
  }
  return h;
}

// The Morton codes of the quantized centres.
std::vector<std::uint64_t> morton_codes(const GaussianMixture& mixture, const CompactHeader& h) {
  const std::uint64_t m_pos = max_code(h.bits.position_bits);
  std::vector<std::uint64_t> code(mixture.size());
  for (std::size_t k = 0; k < mixture.size(); ++k) {
    std::uint64_t c = 0;
    for (int d = 0; d < 3; ++d) c |= spread3(quantize(mixture[k].mean[d], h.position_lo[d], h.position_hi[d], m_pos)) << d;
    code[k] = c;
  }
  return code;
}

// Smallest three: drop the largest component (index in the top 2 bits), made
// positive (q and −q are one rotation); the others lie in [−1/√2, 1/√2], `bits` each.
std::uint64_t rotation_word(const std::array<float, 4>& rotation, int bits) {
  std::array<double, 4> q;
  double norm2 = 0.0;
  for (int j = 0; j < 4; ++j) norm2 += static_cast<double>(rotation[j]) * rotation[j];
  const double inv = 1.0 / std::sqrt(norm2);
  int largest = 0;
  for (int j = 0; j < 4; ++j) {
    q[j] = rotation[j] * inv;
    if (std::abs(q[j]) > std::abs(q[largest])) largest = j;
  }
  if (q[largest] < 0) {
    for (double& v : q) v = -v;
  }
  const std::uint64_t m_rot = max_code(bits);
  auto word = static_cast<std::uint64_t>(largest);
  for (int j = 0; j < 4; ++j) {
    if (j != largest) word = (word << bits) | quantize(q[j], -kHalfSqrt2, kHalfSqrt2, m_rot);
  }
  return word;
}

// One zstd frame that records its content size (the reader checks it against K
// before allocating) and a checksum of the content (a flipped bit is an error, not a
// quietly different model).
std::string compress_frame(const std::string& raw, int level) {
  const std::unique_ptr<ZSTD_CCtx, decltype(&ZSTD_freeCCtx)> cctx(ZSTD_createCCtx(), &ZSTD_freeCCtx);
  if (!cctx) throw std::bad_alloc();
  const auto zstd_check = [](std::size_t r) {
    if (ZSTD_isError(r)) throw std::runtime_error(std::string("zstd compression failed: ") + ZSTD_getErrorName(r));
    return r;
  };
  zstd_check(ZSTD_CCtx_setParameter(cctx.get(), ZSTD_c_compressionLevel, level));
  zstd_check(ZSTD_CCtx_setParameter(cctx.get(), ZSTD_c_checksumFlag, 1));
  zstd_check(ZSTD_CCtx_setParameter(cctx.get(), ZSTD_c_contentSizeFlag, 1));
  std::string payload(ZSTD_compressBound(raw.size()), '\0');
  payload.resize(zstd_check(ZSTD_compress2(cctx.get(), payload.data(), payload.size(), raw.data(), raw.size())));
  return payload;
}

// The file: fixed header, metadata, payload size, payload, CRC-32 of all before it.
std::string assemble_file(const CompactHeader& h, const std::string& metadata, const std::string& payload) {
  io::BinaryWriter w;
  for (char c : kCompactMagic) w.put(c);
  w.put(kCompactFormatVersion);
  w.put(static_cast<std::uint64_t>(h.count));
  for (int bits : {h.bits.position_bits, h.bits.scale_bits, h.bits.rotation_bits, h.bits.intensity_bits}) {
    w.put(static_cast<std::uint8_t>(bits));
  }
  for (const auto* box : {&h.position_lo, &h.position_hi, &h.log_scale_lo, &h.log_scale_hi}) {
    for (float v : *box) w.put(v);
  }
  w.put(static_cast<std::uint64_t>(metadata.size()));
  std::string out = w.take();
  out += metadata;
  io::BinaryWriter tail;
  tail.put(static_cast<std::uint64_t>(payload.size()));
  out += tail.take();
  out += payload;
  io::BinaryWriter checksum;
  checksum.put(crc32_of(out));
  out += checksum.take();
  return out;
}

}  // namespace

std::string encode_compact_checkpoint(const GaussianMixture& mixture, const CheckpointMeta& meta,
                                      const CompactOptions& options, std::vector<std::size_t>* order_out) {
  options.validate();
  const std::string metadata = metadata_text(meta);
  check_checkpoint_mixture(mixture);
  const std::size_t count = mixture.size();
  const CompactHeader h = header_of(mixture, options);
  // The Morton order of the quantized centres: neighbours in the file are
  // neighbours in space, so the gaps between successive codes are small numbers
  // whose high byte planes are nearly all zero.
  const std::vector<std::uint64_t> code = morton_codes(mixture, h);
  std::vector<std::size_t> order(count);
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return code[a] < code[b]; });

  const Layout layout = layout_of(options);
  std::string raw(count * layout.per_gaussian(), '\0');
  const Columns cols(raw.data(), count, layout);
  const std::uint64_t m_scale = max_code(options.scale_bits), m_int = max_code(options.intensity_bits);
  std::uint64_t previous = 0;
  for (std::size_t i = 0; i < count; ++i) {
    const GaussianParams& g = mixture[order[i]];
    cols.position.put(i, code[order[i]] - previous);
    previous = code[order[i]];
    for (int d = 0; d < 3; ++d) {
      cols.scale(d).put(i, quantize(g.log_scale[d], h.log_scale_lo[d], h.log_scale_hi[d], m_scale));
    }
    cols.rotation.put(i, rotation_word(g.rotation, options.rotation_bits));
    cols.intensity.put(i, quantize(sigmoid<double>(g.intensity_logit), 0.0, 1.0, m_int));
  }
  std::string out = assemble_file(h, metadata, compress_frame(raw, options.zstd_level));
  if (order_out) *order_out = std::move(order);
  return out;
}

namespace {

[[noreturn]] void fail_compact(const fs::path& source, const std::string& problem) {
  io::fail_input(source, kWhat + problem);
}

// From version 2 the whole file (header, metadata and payload) is covered by the
// CRC-32 at its end: checked before any other field is trusted.
void check_file_checksum(std::string_view bytes, const fs::path& source) {
  const std::size_t size = bytes.size();
  if (size < kFixedHeaderBytes + kChecksumBytes) {
    fail_compact(source, "truncated: " + std::to_string(size) + " bytes, the header and checksum alone need " +
                             std::to_string(kFixedHeaderBytes + kChecksumBytes));
  }
  std::uint32_t stored = 0;
  std::memcpy(&stored, bytes.data() + size - kChecksumBytes, kChecksumBytes);
  const std::uint32_t computed = crc32_of(bytes.substr(0, size - kChecksumBytes));
  if (stored == computed) return;
  // A cut-short file fails the checksum too; its declared sizes (read only for
  // this message) say which it is.
  std::uint64_t metadata = 0, payload = 0;
  std::memcpy(&metadata, bytes.data() + kFixedHeaderBytes - 16, 8);
  const std::uint64_t room = size - kFixedHeaderBytes - kChecksumBytes;  // for metadata and payload
  if (metadata <= room) std::memcpy(&payload, bytes.data() + kFixedHeaderBytes - 8 + metadata, 8);
  if (metadata > room || payload > room - metadata) {
    fail_compact(source, "truncated: " + std::to_string(size) +
                             " bytes, fewer than its header declares (and the checksum fails)");
  }
  char text[96];
  std::snprintf(text, sizeof text, "checksum mismatch (CRC-32 stored %08x, computed %08x)", stored, computed);
  fail_compact(source, std::string(text) + ": the file was changed or damaged after it was written");
}

// The header's bits and ranges, checked.
void read_bits_and_ranges(io::BinaryReader& r, CompactHeader& h, const fs::path& source) {
  h.bits.position_bits = r.get<std::uint8_t>();
  h.bits.scale_bits = r.get<std::uint8_t>();
  h.bits.rotation_bits = r.get<std::uint8_t>();
  h.bits.intensity_bits = r.get<std::uint8_t>();
  try {
    h.bits.validate();
  } catch (const io::InputError& e) {
    fail_compact(source, std::string("header ") + e.what());
  }
  const char* names[] = {"position", "log-scale"};
  std::array<float, 3>* boxes[] = {&h.position_lo, &h.position_hi, &h.log_scale_lo, &h.log_scale_hi};
  for (auto* box : boxes) {
    for (float& v : *box) v = r.get<float>();
  }
  for (int b = 0; b < 2; ++b) {
    const auto& lo = *boxes[2 * b];
    const auto& hi = *boxes[2 * b + 1];
    for (int d = 0; d < 3; ++d) {
      if (!std::isfinite(lo[d]) || !std::isfinite(hi[d]) || lo[d] > hi[d]) {
        fail_compact(source, std::string("header ") + names[b] + " range of axis " + std::to_string(d) + " [" +
                                 io::number_text(lo[d]) + ", " + io::number_text(hi[d]) +
                                 "] is not finite with lo <= hi");
      }
    }
  }
}

// The metadata and payload sizes against the file's (`trailer`: checksum bytes),
// and K against what the payload can hold, before anything is allocated.
void check_section_sizes(std::string_view bytes, std::size_t trailer, CompactHeader& h, const fs::path& source) {
  const std::size_t size = bytes.size();
  if (h.metadata_bytes > kMaxMetadataBytes) {
    fail_compact(source, "metadata of " + std::to_string(h.metadata_bytes) + " bytes is more than the " +
                             std::to_string(kMaxMetadataBytes) + " allowed");
  }
  if (h.metadata_bytes > size - trailer - kFixedHeaderBytes) {
    fail_compact(source, "truncated: " + std::to_string(size) + " bytes, the header with its " +
                             std::to_string(h.metadata_bytes) + " bytes of metadata needs " +
                             std::to_string(kFixedHeaderBytes + h.metadata_bytes + trailer));
  }
  std::memcpy(&h.payload_bytes, bytes.data() + kFixedHeaderBytes - 8 + h.metadata_bytes, 8);
  const std::uint64_t rest = size - trailer - kFixedHeaderBytes - h.metadata_bytes;
  if (h.payload_bytes > rest) {
    fail_compact(source, "truncated: the payload should be " + std::to_string(h.payload_bytes) +
                             " bytes, the file holds " + std::to_string(rest));
  }
  if (h.payload_bytes < rest) {
    fail_compact(source, std::to_string(rest - h.payload_bytes) + " bytes follow the payload of " +
                             std::to_string(h.payload_bytes) + " bytes");
  }
  // K × bytes per Gaussian must fit in 64 bits and in what a model's payload of this
  // size can hold (kMaxCompressionRatio), before anything that size is allocated.
  const std::uint64_t per = layout_of(h.bits).per_gaussian();
  if (h.count > std::numeric_limits<std::uint64_t>::max() / 64 ||
      h.count * per > std::max(kFreeRawBytes, h.payload_bytes * kMaxCompressionRatio)) {
    fail_compact(source, std::to_string(h.count) + " Gaussians of " + std::to_string(per) +
                             " bytes would be more than " + std::to_string(kMaxCompressionRatio) +
                             " times the payload of " + std::to_string(h.payload_bytes) +
                             " bytes; no model compresses that well (damaged, or not written by hisnegs)");
  }
}

}  // namespace

CompactHeader read_compact_header(std::string_view bytes, const fs::path& source) {
  const std::size_t size = bytes.size();
  if (size == 0) fail_compact(source, "the file is empty");
  const std::size_t magic_bytes = std::min(size, kCompactMagic.size());
  if (std::memcmp(bytes.data(), kCompactMagic.data(), magic_bytes) != 0) {
    fail_compact(source, "the file does not start with the .hgs signature 89 48 47 53 0D 0A 1A 0A");
  }
  if (size < kFixedHeaderBytes) {
    fail_compact(source, "truncated: " + std::to_string(size) + " bytes, the header alone needs " +
                             std::to_string(kFixedHeaderBytes));
  }
  io::BinaryReader r(bytes, source.string(), "compact checkpoint");
  for (std::size_t i = 0; i < kCompactMagic.size(); ++i) (void)r.get<char>();
  CompactHeader h;
  h.file_bytes = size;
  h.version = r.get<std::uint32_t>();
  if (h.version == 0 || h.version > kCompactFormatVersion) {
    fail_compact(source, "format version " + std::to_string(h.version) + " is not one this build reads (1.." +
                             std::to_string(kCompactFormatVersion) + ")");
  }
  std::size_t trailer = 0;
  if (h.version >= kFirstChecksummedVersion) {
    check_file_checksum(bytes, source);
    trailer = kChecksumBytes;
    h.checksummed = true;
  }
  h.count = r.get<std::uint64_t>();
  read_bits_and_ranges(r, h, source);
  h.metadata_bytes = r.get<std::uint64_t>();
  check_section_sizes(bytes, trailer, h, source);
  return h;
}

namespace {

// The metadata: "hisnegs KEY VALUE" lines joined by line feeds, parsed as a PLY's.
CheckpointMeta parse_compact_metadata(std::string_view metadata, const fs::path& source) {
  std::vector<std::string> lines;
  for (std::size_t start = 0; start < metadata.size();) {
    std::size_t end = metadata.find('\n', start);
    if (end == std::string_view::npos) end = metadata.size();
    const std::string_view line = metadata.substr(start, end - start);
    if (const std::string problem = metadata_line_problem(line); !problem.empty()) {
      fail_compact(source, "metadata line " + std::to_string(lines.size() + 1) + " '" + io::printable(line, 60) +
                               "' " + problem);
    }
    lines.emplace_back(line);
    start = end + 1;
    if (end + 1 == metadata.size()) fail_compact(source, "metadata ends with an empty line");
  }
  return checkpoint_meta_from_comments(lines, source);
}

// The payload: one zstd frame that records its size, exactly `count` × `per` bytes.
std::string decompress_payload(std::string_view payload, std::uint64_t count, std::uint64_t per,
                               const fs::path& source) {
  const std::uint64_t expected = count * per;
  const auto fail = [&](const std::string& problem) { fail_compact(source, problem); };
  // RFC 8878 §3.1.1: magic 28 B5 2F FD, then the frame header descriptor, whose
  // bit 2 says the frame ends with a checksum of its content (always written here).
  if (payload.size() < 5 || std::memcmp(payload.data(), "\x28\xb5\x2f\xfd", 4) != 0) {
    fail("the payload is not a zstd frame");
  }
  if ((static_cast<unsigned char>(payload[4]) & 0x04) == 0) fail("the payload's zstd frame has no checksum");
  const unsigned long long content = ZSTD_getFrameContentSize(payload.data(), payload.size());
  if (content == ZSTD_CONTENTSIZE_ERROR) fail("the payload is not a zstd frame");
  if (content == ZSTD_CONTENTSIZE_UNKNOWN) fail("the payload's zstd frame does not record its content size");
  if (content != expected) {
    fail("the payload holds " + std::to_string(content) + " bytes, " + std::to_string(count) + " Gaussians of " +
         std::to_string(per) + " bytes need " + std::to_string(expected));
  }
  const std::size_t frame = ZSTD_findFrameCompressedSize(payload.data(), payload.size());
  if (ZSTD_isError(frame)) fail(std::string("payload: zstd: ") + ZSTD_getErrorName(frame));
  if (frame != payload.size()) {
    fail("the payload's zstd frame is " + std::to_string(frame) + " of its " + std::to_string(payload.size()) +
         " bytes");
  }
  io::check_allocation(source, static_cast<double>(expected) + static_cast<double>(count) * sizeof(GaussianParams),
                       std::to_string(count) + " Gaussians");
  std::string raw(expected, '\0');
  const std::size_t got = ZSTD_decompress(raw.data(), raw.size(), payload.data(), payload.size());
  if (ZSTD_isError(got)) fail(std::string("payload: zstd: ") + ZSTD_getErrorName(got));
  if (got != expected) {
    fail("the payload decompressed to " + std::to_string(got) + " of " + std::to_string(expected) + " bytes");
  }
  return raw;
}

// The inverse of rotation_word: the largest component from the others (unit norm).
std::array<float, 4> rotation_of(std::uint64_t word, int bits) {
  const std::uint64_t m_rot = max_code(bits);
  const int largest = static_cast<int>(word >> (3 * bits));
  std::array<double, 4> q{};
  double small2 = 0.0;
  for (int j = 3, shift = 0; j >= 0; --j) {
    if (j == largest) continue;
    q[j] = dequantize((word >> shift) & m_rot, -kHalfSqrt2, kHalfSqrt2, m_rot);
    small2 += q[j] * q[j];
    shift += bits;
  }
  q[largest] = std::sqrt(std::max(0.0, 1.0 - small2));
  const double inv = 1.0 / std::sqrt(small2 + q[largest] * q[largest]);  // 1 unless bits is tiny
  std::array<float, 4> rotation;
  for (int j = 0; j < 4; ++j) rotation[j] = static_cast<float>(q[j] * inv);
  return rotation;
}

}  // namespace

Checkpoint decode_compact_checkpoint(std::string_view bytes, const fs::path& source) {
  const CompactHeader h = read_compact_header(bytes, source);
  const auto fail = [&](const std::string& problem) { fail_compact(source, problem); };
  Checkpoint out;
  out.meta = parse_compact_metadata(bytes.substr(kFixedHeaderBytes - 8, h.metadata_bytes), source);
  const Layout layout = layout_of(h.bits);
  std::string raw = decompress_payload(bytes.substr(kFixedHeaderBytes + h.metadata_bytes, h.payload_bytes), h.count,
                                       layout.per_gaussian(), source);
  const auto count = static_cast<std::size_t>(h.count);
  const Columns cols(raw.data(), count, layout);
  const int pb = h.bits.position_bits, rb = h.bits.rotation_bits;
  const std::uint64_t m_pos = max_code(pb), m_scale = max_code(h.bits.scale_bits);
  const std::uint64_t m_code = max_code(3 * pb), m_word = max_code(2 + 3 * rb), m_int = max_code(h.bits.intensity_bits);
  const auto where = [](std::size_t i) { return "Gaussian " + std::to_string(i) + ": "; };
  out.mixture.resize(count);
  std::uint64_t code = 0;
  for (std::size_t i = 0; i < count; ++i) {
    GaussianParams& g = out.mixture[i];
    const std::uint64_t gap = cols.position.get(i);
    if (gap > m_code - code) fail(where(i) + "position code beyond " + std::to_string(3 * pb) + " bits");
    code += gap;
    for (int d = 0; d < 3; ++d) {
      g.mean[d] = static_cast<float>(dequantize(compact3(code >> d), h.position_lo[d], h.position_hi[d], m_pos));
      const std::uint64_t c = cols.scale(d).get(i);
      if (c > m_scale) fail(where(i) + "log-scale code " + std::to_string(c) + " beyond its bits");
      g.log_scale[d] = static_cast<float>(dequantize(c, h.log_scale_lo[d], h.log_scale_hi[d], m_scale));
    }
    const std::uint64_t word = cols.rotation.get(i);
    if (word > m_word) fail(where(i) + "rotation code beyond its bits");
    g.rotation = rotation_of(word, rb);
    const std::uint64_t c = cols.intensity.get(i);
    if (c > m_int) fail(where(i) + "intensity code " + std::to_string(c) + " beyond its bits");
    const double a = std::clamp(dequantize(c, 0.0, 1.0, m_int), kIntensityEnd, 1.0 - kIntensityEnd);
    g.intensity_logit = static_cast<float>(logit(a));
  }
  try {
    check_checkpoint_mixture(out.mixture);
  } catch (const std::invalid_argument& e) {
    fail(std::string("decoded ") + e.what());
  }
  return out;
}

CompactHeader save_compact_checkpoint(const fs::path& path, const GaussianMixture& mixture, const CheckpointMeta& meta,
                                      const CompactOptions& options) {
  std::string bytes;
  try {
    bytes = encode_compact_checkpoint(mixture, meta, options);
  } catch (const std::invalid_argument& e) {
    throw std::invalid_argument(io::describe(path, std::string("cannot save checkpoint: ") + e.what()));
  }
  io::write_file_atomic(path, bytes.data(), bytes.size());
  CompactHeader h = read_compact_header(bytes, path);
  return h;
}

Checkpoint load_compact_checkpoint(const fs::path& path) {
  return decode_compact_checkpoint(io::read_file(path), path);
}

}  // namespace hisnegs::gmf
