// SPDX-License-Identifier: Apache-2.0
// The compact checkpoint (gmf/core/compact_checkpoint.hpp): round trips within the
// stated quantization bounds over many random models, exact metadata, every cut
// and corrupted header refused with one line, load_checkpoint choosing the reader
// by the file's first bytes.
#include "gmf/core/compact_checkpoint.hpp"

#include <gtest/gtest.h>
#include <zlib.h>
#include <zstd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <limits>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "gmf/core/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::gmf {
namespace {
namespace fs = std::filesystem;
using hisnegs::testing::ScratchDir;

// Header offsets (docs/file-formats.md "Compact checkpoint").
constexpr std::size_t kVersionAt = 8, kCountAt = 12, kBitsAt = 20, kBoxAt = 24, kMetaSizeAt = 72, kMetaAt = 80;

double sigmoid_d(double x) { return 1.0 / (1.0 + std::exp(-x)); }

// A model with a random box (size 1e-3..1e3, off-centre), optionally flat along
// one axis, random log-scale ranges, quaternions of any norm and logits from
// saturated dark to saturated bright.
GaussianMixture random_model(std::size_t k, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<float> normal(0.0f, 1.0f);
  const double size = std::pow(10.0, -3.0 + 6.0 * u(rng));
  const double centre = (u(rng) - 0.5) * 4.0 * size;
  const int flat_axis = static_cast<int>(rng() % 5);  // 0..2: that axis is one value; 3, 4: none
  const float flat_value = static_cast<float>(centre);
  const double scale_lo = -8.0 + 6.0 * u(rng), scale_span = 5.0 * u(rng);
  GaussianMixture m;
  for (std::size_t i = 0; i < k; ++i) {
    GaussianParams g;
    for (int d = 0; d < 3; ++d) {
      g.mean[d] = d == flat_axis ? flat_value : static_cast<float>(centre + (u(rng) - 0.5) * size);
      g.log_scale[d] = static_cast<float>(scale_lo + scale_span * u(rng));
    }
    const float norm = std::pow(10.0f, static_cast<float>(-3.0 + 6.0 * u(rng)));
    for (float& v : g.rotation) v = normal(rng) * norm;
    if (g.rotation == std::array<float, 4>{0, 0, 0, 0}) g.rotation[0] = 1.0f;
    g.intensity_logit = rng() % 8 == 0 ? (rng() % 2 ? 40.0f : -40.0f) : static_cast<float>(-8.0 + 16.0 * u(rng));
    m.push_back(g);
  }
  return m;
}

CompactOptions random_options(std::mt19937& rng) {
  const auto in = [&](int lo, int hi) { return lo + static_cast<int>(rng() % static_cast<unsigned>(hi - lo + 1)); };
  CompactOptions o;
  o.position_bits = in(8, 21);
  o.scale_bits = in(4, 16);
  o.rotation_bits = in(4, 15);
  o.intensity_bits = in(4, 16);
  o.zstd_level = in(1, 5);  // the level changes the bytes, not the model; keep the test fast
  return o;
}

CheckpointMeta full_compact_meta() {
  CheckpointMeta meta;
  meta.volume_shape_zyx = std::array<int, 3>{60, 512, 512};
  meta.spacing_um = std::array<double, 3>{0.32964851672062956, 0.32964851672062956, 0.9988};
  meta.aspect = std::array<double, 3>{1.0, 1.0, 60 * 0.9988 / (512 * 0.32964851672062956)};
  meta.normalization = "minmax 0 254";
  meta.aggregation = Aggregation::kSoftmax;
  meta.beta = 1.0 / 3.0;  // no short decimal
  meta.extra = {{"source", "/data/op1 neuron.tif"}, {"empty_value", ""}, {"spaced", "  two leading blanks\t"}};
  return meta;
}

// The unit quaternion of `rotation` with the sign that makes its dot with `near` ≥ 0.
std::array<double, 4> unit_like(const std::array<float, 4>& rotation, const std::array<float, 4>& near) {
  double n2 = 0.0, dot = 0.0;
  for (int j = 0; j < 4; ++j) {
    n2 += static_cast<double>(rotation[j]) * rotation[j];
    dot += static_cast<double>(rotation[j]) * near[j];
  }
  const double s = (dot < 0 ? -1.0 : 1.0) / std::sqrt(n2);
  return {rotation[0] * s, rotation[1] * s, rotation[2] * s, rotation[3] * s};
}

// What rounding adds to a bound: half a float ulp of the decoded value b, and the
// double arithmetic of (de)quantizing over [lo, hi].
double slack(double b, double lo, double hi) {
  return 0.5 * std::abs(b) * std::numeric_limits<float>::epsilon() +
         8 * std::numeric_limits<double>::epsilon() * (std::abs(lo) + std::abs(hi));
}

void write_bytes(const fs::path& path, std::string_view bytes) {
  std::ofstream(path, std::ios::binary).write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

template <class T>
void poke(std::string& bytes, std::size_t at, T value) {
  std::memcpy(bytes.data() + at, &value, sizeof value);
}

// The file with its CRC-32 trailer recomputed (zlib's crc32, independent of the
// reader's): a hostile file, not a damaged one, so the checks behind the checksum
// are what refuses it.
std::string resealed(std::string bytes) {
  const std::size_t body = bytes.size() - 4;
  const auto crc = static_cast<std::uint32_t>(::crc32(0L, reinterpret_cast<const Bytef*>(bytes.data()), body));
  poke(bytes, body, crc);
  return bytes;
}

// Expects `f` to throw one io::InputError line that names `source` and holds `expected`.
void expect_refused(const std::function<void()>& f, const std::string& source, const std::string& expected) {
  try {
    f();
    ADD_FAILURE() << "accepted (expected '" << expected << "')";
  } catch (const io::InputError& e) {
    const std::string message = e.what();
    EXPECT_EQ(message.rfind(source + ": ", 0), 0u) << message;
    EXPECT_NE(message.find(expected), std::string::npos) << message;
    EXPECT_EQ(message.find('\n'), std::string::npos) << message;
  }
}

void expect_decode_refused(const std::string& bytes, const std::string& expected) {
  expect_refused([&] { (void)decode_compact_checkpoint(bytes, "m.hgs"); }, "m.hgs", expected);
}

// ----- round trips -----

TEST(CompactCheckpoint, RoundTripStaysWithinTheBoundsOverRandomModels) {
  std::mt19937 rng(2020);
  // The largest error seen as a fraction of its bound, to show the bounds are not vacuous.
  double worst_position = 0, worst_scale = 0, worst_rotation = 0, worst_intensity = 0;
  for (int trial = 0; trial < 300; ++trial) {
    const std::size_t k = trial < 20 ? static_cast<std::size_t>(trial % 3) : 1 + rng() % 400;  // K = 0, 1, 2 first
    const GaussianMixture in = random_model(k, rng);
    const CompactOptions options = trial % 4 == 0 ? CompactOptions{} : random_options(rng);
    std::vector<std::size_t> order;
    const std::string bytes = encode_compact_checkpoint(in, CheckpointMeta{}, options, &order);
    const CompactHeader header = read_compact_header(bytes, "m.hgs");
    const CompactBounds bound = compact_bounds(header);
    const Checkpoint out = decode_compact_checkpoint(bytes, "m.hgs");
    SCOPED_TRACE("trial " + std::to_string(trial) + ", K " + std::to_string(k));
    ASSERT_EQ(out.mixture.size(), k);
    ASSERT_EQ(header.count, k);
    // `order` is a permutation of the input.
    std::vector<std::size_t> sorted = order;
    std::sort(sorted.begin(), sorted.end());
    std::vector<std::size_t> identity(k);
    std::iota(identity.begin(), identity.end(), std::size_t{0});
    ASSERT_EQ(sorted, identity);
    for (std::size_t i = 0; i < k; ++i) {
      const GaussianParams& a = in[order[i]];
      const GaussianParams& b = out.mixture[i];
      for (int d = 0; d < 3; ++d) {
        const double ep = std::abs(static_cast<double>(b.mean[d]) - a.mean[d]);
        ASSERT_LE(ep, bound.position[d] + slack(b.mean[d], header.position_lo[d], header.position_hi[d]))
            << "Gaussian " << i << " axis " << d;
        const double es = std::abs(static_cast<double>(b.log_scale[d]) - a.log_scale[d]);
        ASSERT_LE(es, bound.log_scale[d] + slack(b.log_scale[d], header.log_scale_lo[d], header.log_scale_hi[d]))
            << "Gaussian " << i << " axis " << d;
        if (bound.position[d] > 0) worst_position = std::max(worst_position, ep / bound.position[d]);
        if (bound.log_scale[d] > 0) worst_scale = std::max(worst_scale, es / bound.log_scale[d]);
      }
      const std::array<double, 4> q = unit_like(a.rotation, b.rotation);
      double dq2 = 0.0, n2 = 0.0;
      for (int j = 0; j < 4; ++j) {
        dq2 += (b.rotation[j] - q[j]) * (b.rotation[j] - q[j]);
        n2 += static_cast<double>(b.rotation[j]) * b.rotation[j];
      }
      ASSERT_NEAR(n2, 1.0, 1e-6) << "decoded quaternions are unit";
      ASSERT_LE(std::sqrt(dq2), bound.rotation + 1e-6) << "Gaussian " << i;
      worst_rotation = std::max(worst_rotation, std::sqrt(dq2) / bound.rotation);
      const double ei = std::abs(sigmoid_d(b.intensity_logit) - sigmoid_d(a.intensity_logit));
      ASSERT_LE(ei, bound.intensity + 1e-6) << "Gaussian " << i << " logit " << a.intensity_logit;
      worst_intensity = std::max(worst_intensity, ei / bound.intensity);
    }
  }
  // Uniform quantization reaches nearly half a step somewhere in ~60,000 values;
  // the rotation bound is a worst case over all quaternions, typical errors are
  // a few times smaller.
  EXPECT_GT(worst_position, 0.9);
  EXPECT_GT(worst_scale, 0.9);
  EXPECT_GT(worst_intensity, 0.9);
  EXPECT_GT(worst_rotation, 0.15);
}

TEST(CompactCheckpoint, MetadataRoundTripsExactly) {
  std::mt19937 rng(1);
  const CheckpointMeta meta = full_compact_meta();
  const Checkpoint out = decode_compact_checkpoint(encode_compact_checkpoint(random_model(5, rng), meta), "m.hgs");
  EXPECT_EQ(out.meta, meta);
  EXPECT_EQ(out.meta.beta, 1.0 / 3.0);  // bit for bit
  // A sum model writes no aggregation line and reads back as a sum.
  const CheckpointMeta plain;
  EXPECT_EQ(decode_compact_checkpoint(encode_compact_checkpoint(GaussianMixture{}, plain), "m.hgs").meta, plain);
}

TEST(CompactCheckpoint, EmptyModelRoundTrips) {
  const std::string bytes = encode_compact_checkpoint(GaussianMixture{}, full_compact_meta());
  const Checkpoint out = decode_compact_checkpoint(bytes, "m.hgs");
  EXPECT_TRUE(out.mixture.empty());
  EXPECT_EQ(out.meta, full_compact_meta());
  EXPECT_EQ(read_compact_header(bytes, "m.hgs").count, 0u);
}

TEST(CompactCheckpoint, DegenerateBoxesDecodeExactly) {
  // One Gaussian: every range is a single value, which the header holds exactly.
  GaussianParams g;
  g.mean = {0.123456789f, -7.5f, 3e-20f};
  g.log_scale = {-6.9077f, -2.5f, 0.1f};
  g.rotation = {0.1f, -0.7f, 0.2f, 0.3f};
  g.intensity_logit = 1.7f;
  const Checkpoint one = decode_compact_checkpoint(encode_compact_checkpoint(GaussianMixture({g}), {}), "m.hgs");
  ASSERT_EQ(one.mixture.size(), 1u);
  EXPECT_EQ(one.mixture[0].mean, g.mean);
  EXPECT_EQ(one.mixture[0].log_scale, g.log_scale);

  // Many Gaussians on the plane z = 0.25 with one log-scale along y: those stay exact.
  std::mt19937 rng(3);
  GaussianMixture flat = random_model(200, rng);
  for (GaussianParams& p : flat) {
    p.mean[2] = 0.25f;
    p.log_scale[1] = -4.0f;
  }
  const Checkpoint out = decode_compact_checkpoint(encode_compact_checkpoint(flat, {}), "m.hgs");
  for (const GaussianParams& p : out.mixture) {
    EXPECT_EQ(p.mean[2], 0.25f);
    EXPECT_EQ(p.log_scale[1], -4.0f);
  }
}

TEST(CompactCheckpoint, StoresGaussiansInMortonOrder) {
  // Eight Gaussians at the corners of a cube, given in reverse Z-curve order.
  GaussianMixture m;
  for (int c = 7; c >= 0; --c) {
    GaussianParams g;
    g.mean = {static_cast<float>(c & 1), static_cast<float>((c >> 1) & 1), static_cast<float>((c >> 2) & 1)};
    m.push_back(g);
  }
  std::vector<std::size_t> order;
  const Checkpoint out = decode_compact_checkpoint(encode_compact_checkpoint(m, {}, {}, &order), "m.hgs");
  EXPECT_EQ(order, (std::vector<std::size_t>{7, 6, 5, 4, 3, 2, 1, 0}));
  for (int c = 0; c < 8; ++c) {
    EXPECT_EQ(out.mixture[c].mean, m[order[c]].mean) << "corners are the box's ends, which decode exactly";
  }
}

TEST(CompactCheckpoint, HeaderRecordsCountBitsSizeAndBox) {
  std::mt19937 rng(4);
  const GaussianMixture m = random_model(50, rng);
  CompactOptions o;
  o.position_bits = 18;
  o.intensity_bits = 11;
  const std::string bytes = encode_compact_checkpoint(m, full_compact_meta(), o);
  const CompactHeader h = read_compact_header(bytes, "m.hgs");
  EXPECT_EQ(h.version, kCompactFormatVersion);
  EXPECT_EQ(h.count, 50u);
  EXPECT_EQ(h.bits.position_bits, 18);
  EXPECT_EQ(h.bits.scale_bits, CompactOptions{}.scale_bits);
  EXPECT_EQ(h.bits.intensity_bits, 11);
  EXPECT_EQ(h.file_bytes, bytes.size());
  EXPECT_EQ(kMetaAt + h.metadata_bytes + 8 + h.payload_bytes + 4, bytes.size());  // + the CRC-32
  EXPECT_TRUE(h.checksummed);
  float lo = m[0].mean[0], hi = lo;
  for (const GaussianParams& g : m) {
    lo = std::min(lo, g.mean[0]);
    hi = std::max(hi, g.mean[0]);
  }
  EXPECT_EQ(h.position_lo[0], lo);
  EXPECT_EQ(h.position_hi[0], hi);
  EXPECT_DOUBLE_EQ(compact_bounds(h).position[0], 0.5 * (static_cast<double>(hi) - lo) / ((1 << 18) - 1));
  EXPECT_DOUBLE_EQ(compact_bounds(h).intensity, 0.5 / 2047 + 1e-7);
}

TEST(CompactCheckpoint, IsSmallerThanThePly) {
  // 1000 Gaussians spread along a curve, as a neuron's are: well under 44 B each.
  std::mt19937 rng(5);
  std::normal_distribution<float> jitter(0.0f, 0.01f);
  GaussianMixture m = random_model(1000, rng);
  for (std::size_t i = 0; i < m.size(); ++i) {
    const float t = static_cast<float>(i) / 1000.0f;
    m[i].mean = {std::cos(6 * t) + jitter(rng), std::sin(6 * t) + jitter(rng), 0.3f * t + jitter(rng)};
  }
  const std::string bytes = encode_compact_checkpoint(m, full_compact_meta());
  EXPECT_LT(static_cast<double>(bytes.size()) / 1000.0, 16.0) << bytes.size();
}

// ----- refused input -----

TEST(CompactCheckpoint, CutShortFileIsRefusedAtEveryLength) {
  std::mt19937 rng(6);
  const std::string bytes = encode_compact_checkpoint(random_model(20, rng), full_compact_meta());
  ASSERT_NO_THROW((void)decode_compact_checkpoint(bytes, "m.hgs"));
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    SCOPED_TRACE("length " + std::to_string(n) + " of " + std::to_string(bytes.size()));
    expect_decode_refused(bytes.substr(0, n), n == 0 ? "empty" : "truncated");
  }
  // Through load_checkpoint (every command's reader), a few lengths including a
  // partial signature: one line, naming the file.
  ScratchDir dir;
  const fs::path path = dir / "m.hgs";
  for (std::size_t n : {std::size_t{1}, std::size_t{5}, std::size_t{40}, bytes.size() / 2, bytes.size() - 1}) {
    write_bytes(path, std::string_view(bytes).substr(0, n));
    expect_refused([&] { (void)load_checkpoint(path); }, path.string(), "compact checkpoint: truncated");
  }
}

TEST(CompactCheckpoint, TrailingBytesAreRefused) {
  std::mt19937 rng(7);
  std::string bytes = encode_compact_checkpoint(random_model(3, rng), {});
  expect_decode_refused(bytes + "x", "checksum mismatch");
  bytes.insert(bytes.size() - 4, "x");  // after the payload, inside the checksum
  expect_decode_refused(resealed(bytes), "1 bytes follow the payload");
}

// Issue 32, item 10: the CRC-32 covers the header, the metadata and the payload, so
// every single-bit flip anywhere in a file is refused (before: 8 of 100 random
// flips were read as another model, e.g. x max 2.04e38 from a flip at byte 0x27).
TEST(CompactCheckpoint, EverySingleBitFlipIsRefused) {
  std::mt19937 rng(12);
  const std::string bytes = encode_compact_checkpoint(random_model(12, rng), full_compact_meta());
  ASSERT_NO_THROW((void)decode_compact_checkpoint(bytes, "m.hgs"));
  int refused = 0, checksum = 0;
  for (std::size_t at = 0; at < bytes.size(); ++at) {
    for (int bit = 0; bit < 8; ++bit) {
      std::string flipped = bytes;
      flipped[at] = static_cast<char>(flipped[at] ^ (1 << bit));
      try {
        (void)decode_compact_checkpoint(flipped, "m.hgs");
        ADD_FAILURE() << "a flip of bit " << bit << " of byte " << at << " was accepted";
      } catch (const io::InputError& e) {
        ++refused;
        checksum += std::string(e.what()).find("checksum mismatch") != std::string::npos;
      }
    }
  }
  EXPECT_EQ(refused, static_cast<int>(8 * bytes.size()));
  EXPECT_GT(checksum, refused * 9 / 10);  // the others: signature, version, sizes
}

// Version 1 files (no checksum) are still read, and say so.
TEST(CompactCheckpoint, VersionOneWithoutChecksumIsStillRead) {
  std::mt19937 rng(13);
  const GaussianMixture m = random_model(9, rng);
  const std::string v2 = encode_compact_checkpoint(m, full_compact_meta());
  std::string v1 = v2.substr(0, v2.size() - 4);
  poke<std::uint32_t>(v1, kVersionAt, 1);
  const CompactHeader h1 = read_compact_header(v1, "v1.hgs"), h2 = read_compact_header(v2, "v2.hgs");
  EXPECT_FALSE(h1.checksummed);
  EXPECT_TRUE(h2.checksummed);
  EXPECT_EQ(h2.version, 2u);
  const Checkpoint a = decode_compact_checkpoint(v1, "v1.hgs"), b = decode_compact_checkpoint(v2, "v2.hgs");
  ASSERT_EQ(a.mixture.size(), b.mixture.size());
  for (std::size_t k = 0; k < a.mixture.size(); ++k) {
    EXPECT_EQ(a.mixture[k].mean, b.mixture[k].mean) << k;
    EXPECT_EQ(a.mixture[k].log_scale, b.mixture[k].log_scale) << k;
    EXPECT_EQ(a.mixture[k].rotation, b.mixture[k].rotation) << k;
    EXPECT_EQ(a.mixture[k].intensity_logit, b.mixture[k].intensity_logit) << k;
  }
}

// Issue 32, item 11: a small file cannot make a reader allocate for a huge K. A
// 2.5 KB file declaring 5,000,000 Gaussians (before: 327 MB in `info`) is refused
// from its header; a regular grid, the most compressible model a fit could start
// from, is not.
TEST(CompactCheckpoint, KIsBoundedByWhatThePayloadCanHold) {
  std::mt19937 rng(14);
  std::string bytes = encode_compact_checkpoint(random_model(100, rng), {});
  poke<std::uint64_t>(bytes, kCountAt, 5'000'000);
  expect_refused([&] { (void)read_compact_header(resealed(bytes), "k.hgs"); }, "k.hgs",
                 "5000000 Gaussians of 14 bytes would be more than 1024 times the payload");
  // 64³ Gaussians on a grid, one scale, rotation and intensity: 3.5 MiB of columns.
  GaussianMixture grid;
  for (int i = 0; i < 64 * 64 * 64; ++i) {
    GaussianParams g;
    g.mean = {(i % 64) / 32.0f - 1.0f, (i / 64 % 64) / 32.0f - 1.0f, (i / 4096) / 32.0f - 1.0f};
    g.log_scale = {-4.0f, -4.0f, -4.0f};
    grid.push_back(g);
  }
  CompactOptions fast;
  fast.zstd_level = 3;
  const std::string file = encode_compact_checkpoint(grid, {}, fast);
  const CompactHeader h = read_compact_header(file, "grid.hgs");
  EXPECT_GT(h.count * 14, 100 * h.payload_bytes);  // it does compress very well
  EXPECT_EQ(decode_compact_checkpoint(file, "grid.hgs").mixture.size(), grid.size());
}

struct HeaderCorruption {
  const char* name;
  std::function<void(std::string&)> corrupt;
  const char* expected;
};

class CompactBadHeader : public ::testing::TestWithParam<HeaderCorruption> {};

TEST_P(CompactBadHeader, IsRefusedWithOneLine) {
  std::mt19937 rng(8);
  CheckpointMeta meta = full_compact_meta();
  std::string bytes = encode_compact_checkpoint(random_model(30, rng), meta);
  GetParam().corrupt(bytes);
  try {  // damaged: the checksum fails, unless a check before it (signature, version, size) refuses it first
    (void)decode_compact_checkpoint(bytes, "m.hgs");
    ADD_FAILURE() << "accepted";
  } catch (const io::InputError& e) {
    const std::string m = e.what();
    EXPECT_TRUE(m.find("checksum mismatch") != std::string::npos || m.find(GetParam().expected) != std::string::npos ||
                m.find("truncated") != std::string::npos)
        << m;
  }
  expect_decode_refused(resealed(bytes), GetParam().expected);  // hostile: the checks behind the checksum
}

std::uint64_t metadata_size(const std::string& bytes) {
  std::uint64_t m;
  std::memcpy(&m, bytes.data() + kMetaSizeAt, 8);
  return m;
}

INSTANTIATE_TEST_SUITE_P(
    CompactCheckpoint, CompactBadHeader,
    ::testing::Values(
        HeaderCorruption{"magic", [](std::string& b) { b[1] = 'h'; }, "does not start with the .hgs signature"},
        HeaderCorruption{"version_3", [](std::string& b) { poke<std::uint32_t>(b, kVersionAt, 3); },
                         "format version 3 is not one this build reads"},
        HeaderCorruption{"version_0", [](std::string& b) { poke<std::uint32_t>(b, kVersionAt, 0); },
                         "format version 0"},
        HeaderCorruption{"count_plus_one", [](std::string& b) { poke<std::uint64_t>(b, kCountAt, 31); },
                         "31 Gaussians of 14 bytes need 434"},
        HeaderCorruption{"count_huge", [](std::string& b) { poke<std::uint64_t>(b, kCountAt, std::uint64_t{1} << 60); },
                         "no model compresses that well"},
        HeaderCorruption{"count_past_the_frame",
                         [](std::string& b) { poke<std::uint64_t>(b, kCountAt, std::uint64_t{1} << 40); },
                         "no model compresses that well"},
        HeaderCorruption{"position_bits", [](std::string& b) { b[kBitsAt] = 40; },
                         "header position_bits = 40: must be in 8..21"},
        HeaderCorruption{"scale_bits", [](std::string& b) { b[kBitsAt + 1] = 3; }, "header scale_bits = 3"},
        HeaderCorruption{"rotation_bits", [](std::string& b) { b[kBitsAt + 2] = 16; }, "header rotation_bits = 16"},
        HeaderCorruption{"intensity_bits", [](std::string& b) { b[kBitsAt + 3] = 0; }, "header intensity_bits = 0"},
        HeaderCorruption{"box_nan",
                         [](std::string& b) { poke(b, kBoxAt + 4, std::numeric_limits<float>::quiet_NaN()); },
                         "header position range of axis 1"},
        HeaderCorruption{"box_inverted", [](std::string& b) { poke(b, kBoxAt, 1e30f); },
                         "header position range of axis 0 [1e+30, "},
        HeaderCorruption{"log_scale_inf",
                         [](std::string& b) { poke(b, kBoxAt + 24 + 12, std::numeric_limits<float>::infinity()); },
                         "header log-scale range of axis 0"},
        HeaderCorruption{"metadata_huge",
                         [](std::string& b) { poke<std::uint64_t>(b, kMetaSizeAt, std::uint64_t{1} << 62); },
                         "metadata of 4611686018427387904 bytes is more than"},
        HeaderCorruption{"metadata_past_the_end",
                         [](std::string& b) { poke<std::uint64_t>(b, kMetaSizeAt, b.size()); },
                         "truncated"},
        HeaderCorruption{"payload_size_larger",
                         [](std::string& b) {
                           const std::size_t at = kMetaAt + metadata_size(b);
                           poke<std::uint64_t>(b, at, b.size() - at - 8 - 4 + 1);
                         },
                         "truncated: the payload should be"},
        HeaderCorruption{"payload_size_smaller",
                         [](std::string& b) {
                           const std::size_t at = kMetaAt + metadata_size(b);
                           poke<std::uint64_t>(b, at, b.size() - at - 8 - 4 - 1);
                         },
                         "1 bytes follow the payload"},
        HeaderCorruption{"metadata_foreign_line", [](std::string& b) { b[kMetaAt] = 'x'; },
                         "metadata line 1 'xisnegs format_version 1' is not 'hisnegs KEY VALUE'"},
        HeaderCorruption{"metadata_control_byte", [](std::string& b) { b[kMetaAt + 3] = '\x01'; },
                         "metadata line 1 'his?egs format_version 1' holds a control character"},
        HeaderCorruption{"metadata_bad_value",
                         [](std::string& b) {
                           const std::size_t at = b.find("volume_shape 60");
                           b[at + 13] = 'x';
                         },
                         "comment hisnegs volume_shape: expected three positive integers"},
        HeaderCorruption{"metadata_newer_version",
                         [](std::string& b) { b[b.find("format_version 1") + 15] = '7'; },
                         "format_version 7 is newer than this build supports"},
        HeaderCorruption{"payload_checksum", [](std::string& b) { b[b.size() - 5] ^= 0x55; },
                         "payload: zstd: Restored data doesn't match checksum"},
        HeaderCorruption{"payload_flipped_byte", [](std::string& b) { b[b.size() - 64] ^= 0x10; }, "payload: zstd: "},
        HeaderCorruption{"payload_magic",
                         [](std::string& b) {
                           const std::size_t at = kMetaAt + metadata_size(b) + 8;
                           b[at] = 0;
                         },
                         "the payload is not a zstd frame"}),
    [](const ::testing::TestParamInfo<HeaderCorruption>& info) { return std::string(info.param.name); });

// A valid file whose payload content is changed by `edit` (then compressed again
// with `checksum` and `content_size` flags): for codes a writer never makes.
std::string with_payload(const GaussianMixture& m, const CompactOptions& options,
                         const std::function<void(std::string&)>& edit, bool checksum = true,
                         bool content_size = true) {
  const std::string file = encode_compact_checkpoint(m, {}, options);
  const std::size_t payload_at = kMetaAt + metadata_size(file) + 8;
  const std::string_view payload = std::string_view(file).substr(payload_at, file.size() - payload_at - 4);
  std::string raw(ZSTD_getFrameContentSize(payload.data(), payload.size()), '\0');
  EXPECT_EQ(ZSTD_decompress(raw.data(), raw.size(), payload.data(), payload.size()), raw.size());
  edit(raw);
  ZSTD_CCtx* cctx = ZSTD_createCCtx();
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_checksumFlag, checksum ? 1 : 0);
  ZSTD_CCtx_setParameter(cctx, ZSTD_c_contentSizeFlag, content_size ? 1 : 0);
  std::string z(ZSTD_compressBound(raw.size()), '\0');
  const std::size_t n = ZSTD_compress2(cctx, z.data(), z.size(), raw.data(), raw.size());
  ZSTD_freeCCtx(cctx);
  EXPECT_FALSE(ZSTD_isError(n));
  z.resize(n);
  std::string rebuilt = file.substr(0, payload_at - 8);
  rebuilt.append(8, '\0');
  poke<std::uint64_t>(rebuilt, payload_at - 8, z.size());
  return resealed(rebuilt + z + std::string(4, '\0'));
}

TEST(CompactCheckpoint, CodesBeyondTheirBitsAreRefused) {
  std::mt19937 rng(9);
  const GaussianMixture m = random_model(10, rng);
  CompactOptions o;
  o.position_bits = 8;   // 24-bit Morton codes in 3 planes
  o.scale_bits = 4;      // one plane, codes 0..15
  o.rotation_bits = 9;   // 29-bit words in 4 planes
  o.intensity_bits = 4;  // one plane, codes 0..15
  const std::size_t k = m.size();
  // Plane offsets: gaps 3 planes, log-scales 3 × 1, rotation 4, intensity 1.
  EXPECT_NO_THROW((void)decode_compact_checkpoint(with_payload(m, o, [](std::string&) {}), "m.hgs"));
  expect_decode_refused(with_payload(m, o, [&](std::string& r) { r[3 * k + 2] = '\x10'; }),
                        "Gaussian 2: log-scale code 16 beyond its bits");
  expect_decode_refused(with_payload(m, o, [&](std::string& r) { r[6 * k + 3 * k + 5] = '\x20'; }),
                        "Gaussian 5: rotation code beyond its bits");
  expect_decode_refused(with_payload(m, o, [&](std::string& r) { r[10 * k + 9] = '\xff'; }),
                        "Gaussian 9: intensity code 255 beyond its bits");
  // Two gaps of the largest code: their sum leaves the 24 bits.
  expect_decode_refused(with_payload(m, o,
                                     [&](std::string& r) {
                                       for (std::size_t p = 0; p < 3; ++p) r[p * k + 0] = r[p * k + 1] = '\xff';
                                     }),
                        "Gaussian 1: position code beyond 24 bits");
}

TEST(CompactCheckpoint, PayloadWithoutChecksumOrContentSizeIsRefused) {
  std::mt19937 rng(10);
  const GaussianMixture m = random_model(10, rng);
  const auto same = [](std::string&) {};
  expect_decode_refused(with_payload(m, {}, same, /*checksum=*/false), "zstd frame has no checksum");
  expect_decode_refused(with_payload(m, {}, same, true, /*content_size=*/false), "does not record its content size");
}

// ----- load_checkpoint and saving -----

TEST(CompactCheckpoint, LoadCheckpointChoosesTheReaderByContentNotName) {
  ScratchDir dir;
  std::mt19937 rng(11);
  const GaussianMixture m = random_model(40, rng);
  const CheckpointMeta meta = full_compact_meta();
  // A compact file named .ply and a PLY named .hgs both load.
  const CompactHeader h = save_compact_checkpoint(dir / "compact.ply", m, meta);
  EXPECT_EQ(h.file_bytes, fs::file_size(dir / "compact.ply"));
  save_checkpoint(dir / "plain.hgs", m, meta);
  const Checkpoint from_compact = load_checkpoint(dir / "compact.ply");
  const Checkpoint decoded = decode_compact_checkpoint(io::read_file(dir / "compact.ply"), dir / "compact.ply");
  ASSERT_EQ(from_compact.mixture.size(), m.size());
  EXPECT_EQ(std::memcmp(from_compact.mixture.data(), decoded.mixture.data(), m.size() * sizeof(GaussianParams)), 0);
  EXPECT_EQ(from_compact.meta, meta);
  const Checkpoint from_ply = load_checkpoint(dir / "plain.hgs");
  EXPECT_EQ(std::memcmp(from_ply.mixture.data(), m.data(), m.size() * sizeof(GaussianParams)), 0);
  EXPECT_EQ(from_ply.meta, meta);
  // Errors name the file and come from the reader the content chose.
  write_bytes(dir / "bad.hgs", "ply\nformat ascii 1.0\n");
  expect_refused([&] { (void)load_checkpoint(dir / "bad.hgs"); }, (dir / "bad.hgs").string(), "");
  try {
    (void)load_checkpoint(dir / "bad.hgs");
  } catch (const io::InputError& e) {
    EXPECT_EQ(std::string(e.what()).find("compact"), std::string::npos) << e.what();
  }
}

TEST(CompactCheckpoint, SaveRefusesBadInputAndWritesNothing) {
  ScratchDir dir;
  std::mt19937 rng(12);
  GaussianMixture m = random_model(4, rng);
  const fs::path out = dir / "out.hgs";
  m[2].log_scale[1] = std::numeric_limits<float>::quiet_NaN();
  try {
    (void)save_compact_checkpoint(out, m, {});
    ADD_FAILURE() << "saved a NaN";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(out.string() + ": cannot save checkpoint: gaussian 2: scale_1 is nan"),
              std::string::npos)
        << e.what();
  }
  m[2].log_scale[1] = 0.0f;
  m[3].rotation = {0.0f, 0.0f, 0.0f, 0.0f};
  EXPECT_THROW((void)save_compact_checkpoint(out, m, {}), std::invalid_argument);
  m[3].rotation = {1.0f, 0.0f, 0.0f, 0.0f};
  CheckpointMeta meta;
  meta.extra = {{"k", "line\nbreak"}};
  EXPECT_THROW((void)save_compact_checkpoint(out, m, meta), std::invalid_argument);
  // What a PLY header could not hold either: a control byte, a line over 64 KiB.
  meta.extra = {{"k", "bell\x07"}};
  EXPECT_THROW((void)save_compact_checkpoint(out, m, meta), std::invalid_argument);
  meta.extra = {{"k", std::string(70000, 'x')}};
  EXPECT_THROW((void)save_compact_checkpoint(out, m, meta), std::invalid_argument);
  CompactOptions o;
  o.position_bits = 22;
  expect_refused([&] { (void)save_compact_checkpoint(out, m, {}, o); }, "position_bits = 22", "must be in 8..21");
  EXPECT_TRUE(dir.entries().empty());
  // And the valid model saves.
  (void)save_compact_checkpoint(out, m, {});
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"out.hgs"});
}

}  // namespace
}  // namespace hisnegs::gmf
