// SPDX-License-Identifier: Apache-2.0
// Tests of io/vdb_validate: every file OpenVDB writes (value types, maps, half
// floats, compressions, instances, metadata types, points) passes the walk, which
// lands exactly on each descriptor's block and end positions; truncations and the
// hostile numbers OpenVDB would trust (string lengths, counts, chunk sizes) are
// refused with one line; and any single-byte corruption either is refused or reads
// through OpenVDB as a clean InputError or a grid.
#include "io/vdb_validate.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "io/error.hpp"
#include "io/sparse_grid.hpp"
#include "tests/io/vdb_fixtures.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {

using Depth = VdbGridCheck::Depth;
using testing::vdb_metadata_registered;

bool registered(const std::string& type) { return vdb_metadata_registered(type); }

std::vector<char> read_all(const std::filesystem::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

void write_all(const std::filesystem::path& p, const std::vector<char>& bytes) {
  std::ofstream out(p, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
}

// Offset of the first occurrence of `text` in `bytes` (-1 if absent).
std::ptrdiff_t find(const std::vector<char>& bytes, const std::string& text) {
  const auto it = std::search(bytes.begin(), bytes.end(), text.begin(), text.end());
  return it == bytes.end() ? -1 : it - bytes.begin();
}

class VdbValidate : public ::testing::Test {
 protected:
  testing::ScratchDir dir_;
};

TEST_F(VdbValidate, EveryValueTypeMapAndCompressionWalksToItsEnd) {
  for (const std::uint32_t c : testing::vdb_compressions()) {
    SCOPED_TRACE("compression " + std::to_string(c));
    const auto path = dir_ / ("all" + std::to_string(c) + ".vdb");
    const testing::EveryKindFile written = testing::write_every_kind_vdb(path, c);
    const VdbFileCheck check = validate_vdb_file(path, registered);
    EXPECT_EQ(check.file_version, testing::openvdb_file_version());
    ASSERT_EQ(check.grids.size(), written.names.size());
    for (std::size_t k = 0; k < check.grids.size(); ++k) {
      const VdbGridCheck& g = check.grids[k];
      SCOPED_TRACE(g.name);
      EXPECT_EQ(g.name, written.names[k]);
      if (g.name == "instance") {
        EXPECT_TRUE(g.instance);
      } else {
        EXPECT_EQ(g.depth, Depth::kBuffers);
      }
      if (!g.instance) {
        EXPECT_GT(g.leaves, 0);
      }
    }
    EXPECT_TRUE(check.grids[6].half_float);
    EXPECT_EQ(check.grids[0].leaves, written.float_leaves);
  }
}

TEST_F(VdbValidate, HisnegsGridsAndPointsPass) {
  Volume vol;
  vol.nx = 40;
  vol.ny = 30;
  vol.nz = 12;
  vol.voxels.assign(vol.size(), 0.0f);
  for (int x = 5; x < 35; ++x) vol.at(x, 15, 6) = 0.8f;
  vol.source = "test";
  vol.normalization.method = NormalizationMethod::kMinMax;
  SparseGridOptions options;
  options.background_fraction = 0.05;
  const auto path = dir_ / "grid.vdb";
  write_vdb(path, build_sparse_grid(vol, Eigen::Vector3d(1.0, 0.75, 0.3), options));
  const VdbFileCheck check = validate_vdb_file(path, registered);
  ASSERT_EQ(check.grids.size(), 2u);
  EXPECT_EQ(check.grids[0].name, "volume");
  EXPECT_EQ(check.grids[0].depth, Depth::kBuffers);
  EXPECT_EQ(check.grids[1].name, "background");

  const auto ppath = dir_ / "points.vdb";
  const std::int64_t point_leaves = testing::write_points_vdb(ppath);
  const VdbFileCheck pcheck = validate_vdb_file(ppath, registered);
  ASSERT_EQ(pcheck.grids.size(), 1u);
  EXPECT_EQ(pcheck.grids[0].depth, Depth::kBuffers);  // multi-pass point buffers walked too
  EXPECT_EQ(pcheck.grids[0].leaves, point_leaves);
}

// OpenVDB reads a grid's values as halves when its metadata "is_saved_as_half_float"
// says so, whatever the descriptor's "_HalfFloat" suffix says: the walk follows the
// metadata, so a file whose key was renamed or cleared is refused, not handed to
// OpenVDB to read full floats where halves were written.
TEST_F(VdbValidate, HalfValuesFollowTheGridMetadata) {
  for (const std::uint32_t c : testing::vdb_compressions()) {
    SCOPED_TRACE("compression " + std::to_string(c));
    const auto path = dir_ / "all.vdb";
    (void)testing::write_every_kind_vdb(path, c);
    const std::vector<char> bytes = read_all(path);
    const std::string key = "is_saved_as_half_float";
    const std::ptrdiff_t at = find(bytes, key);
    ASSERT_GT(at, 0);
    const auto bad = dir_ / "bad.vdb";
    std::vector<char> renamed = bytes;
    renamed[static_cast<std::size_t>(at)] = 'j';
    write_all(bad, renamed);
    EXPECT_THROW((void)validate_vdb_file(bad, registered), InputError);
    // The bool value follows its name and type strings ("bool") and its size.
    const std::size_t value_at = static_cast<std::size_t>(at) + key.size() + 4 + 4 + 4;
    ASSERT_EQ(bytes[value_at], 1);
    std::vector<char> cleared = bytes;
    cleared[value_at] = 0;
    write_all(bad, cleared);
    EXPECT_THROW((void)validate_vdb_file(bad, registered), InputError);
    cleared[value_at] = 2;  // any nonzero byte is true, as for OpenVDB
    write_all(bad, cleared);
    EXPECT_TRUE(validate_vdb_file(bad, registered).grids[6].half_float);
  }
}

// `hisnegs info` loads the grids whose leaf buffers the walk checked: every kind
// here, bool and mask included, and point data, whose descriptor, array metadata,
// pages and voxel offsets the walk bounds before OpenVDB allocates by them.
TEST_F(VdbValidate, InspectLoadsCheckedGridsPointsIncluded) {
  const auto path = dir_ / "all.vdb";
  const testing::EveryKindFile written = testing::write_every_kind_vdb(path, testing::vdb_compressions().front());
  const std::vector<VdbGridSummary> grids = inspect_vdb(path);
  ASSERT_EQ(grids.size(), written.names.size());
  for (const VdbGridSummary& g : grids) {
    EXPECT_TRUE(g.values_read) << g.name;
    EXPECT_GT(g.active_voxels, 0) << g.name;
  }

  const auto ppath = dir_ / "points.vdb";
  const std::int64_t leaves = testing::write_points_vdb(ppath);
  std::vector<char> bytes = read_all(ppath);
  const std::vector<VdbGridSummary> pgrids = inspect_vdb(ppath);
  ASSERT_EQ(pgrids.size(), 1u);
  EXPECT_TRUE(pgrids[0].values_read);
  EXPECT_EQ(pgrids[0].value_type, "ptdataidx32");
  EXPECT_EQ(pgrids[0].leaf_count, leaves);
  EXPECT_EQ(pgrids[0].active_voxels, std::stoll(pgrids[0].metadata.at("file_voxel_count")));
  EXPECT_GT(pgrids[0].active_voxels, 0);

  // 2^56 written over any 8 bytes of the buffers (a page size, an array's bytes or
  // length, the descriptor's count...): refused by the walk, or read as it is.
  std::int64_t block_pos = 0;
  const std::ptrdiff_t type_at = find(bytes, "Tree_ptdataidx32_5_4_3");
  ASSERT_GT(type_at, 0);
  std::memcpy(&block_pos, bytes.data() + type_at + 22 + 4 + 8, 8);  // type, empty parent, grid position
  const std::int64_t huge = (std::int64_t{1} << 56) + 257;
  for (std::int64_t at = block_pos; at + 8 <= static_cast<std::int64_t>(bytes.size()); at += 8) {
    std::vector<char> b = bytes;
    std::memcpy(b.data() + at, &huge, 8);
    write_all(dir_ / "bad.vdb", b);
    try {
      const std::vector<VdbGridSummary> bad = inspect_vdb(dir_ / "bad.vdb");
      ASSERT_EQ(bad.size(), 1u);
    } catch (const InputError& e) {
      EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
    }
  }

  // Nor does read_vdb: a `volume` that is not a float grid is refused before OpenVDB reads it.
  (void)testing::write_points_vdb(dir_ / "pv.vdb", "volume");
  try {
    (void)read_vdb(dir_ / "pv.vdb");
    ADD_FAILURE() << "a point grid named volume was read";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("grid 'volume' is Tree_ptdataidx32_5_4_3, not a float grid"),
              std::string::npos)
        << e.what();
  }
}

// A small hisnegs .vdb and its bytes, for the corruption tests.
struct Sample {
  std::filesystem::path path;
  std::vector<char> bytes;
};

Sample small_file(const testing::ScratchDir& dir) {
  Sample s{dir / "small.vdb", {}};
  testing::write_small_vdb(s.path);
  s.bytes = read_all(s.path);
  return s;
}

void expect_refused(const std::filesystem::path& path, const std::string& needle) {
  try {
    (void)validate_vdb_file(path, registered);
    ADD_FAILURE() << "accepted; expected an error containing '" << needle << "'";
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find(needle), std::string::npos) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    EXPECT_EQ(what.rfind(path.string(), 0), 0u) << what;
  }
}

TEST_F(VdbValidate, EveryTruncationIsRefused) {
  const Sample s = small_file(dir_);
  for (std::size_t n = 0; n < s.bytes.size(); n += (n < 400 ? 1 : 37)) {
    SCOPED_TRACE("length " + std::to_string(n));
    const auto cut = dir_ / "cut.vdb";
    write_all(cut, std::vector<char>(s.bytes.begin(), s.bytes.begin() + static_cast<std::ptrdiff_t>(n)));
    EXPECT_THROW((void)validate_vdb_file(cut, registered), InputError);
  }
}

TEST_F(VdbValidate, HostileNumbersAreRefusedBeforeOpenVdbSeesThem) {
  const Sample s = small_file(dir_);
  const auto bad = dir_ / "bad.vdb";
  auto patch = [&](std::ptrdiff_t at, const auto& value) {
    ASSERT_GE(at, 0);
    std::vector<char> b = s.bytes;
    std::memcpy(b.data() + at, &value, sizeof(value));
    write_all(bad, b);
  };
  // The grid type's string length (the 8 patched bytes made OpenVDB take 10.5 GB).
  const std::ptrdiff_t type_at = find(s.bytes, "Tree_float_5_4_3") - 4;
  patch(type_at, std::uint32_t{0xFFFFFFF0u});
  expect_refused(bad, "grid type needs 4294967280 bytes");
  // A metadata string's length.
  patch(find(s.bytes, "a.tif") - 4, std::uint32_t{2000000000u});
  expect_refused(bad, "metadata value needs 2000000000 bytes");
  // A fixed-size metadata value stating another size.
  patch(find(s.bytes, "vec3i") + 5, std::uint32_t{4096});
  expect_refused(bad, "states 4096 bytes, not 12");
  // The descriptor's end position past the file.
  const std::ptrdiff_t end_at = type_at + 4 + 16 + 4 + 16;
  patch(end_at, std::int64_t{1} << 40);
  expect_refused(bad, "outside its place in the file");
  // The number of grids and of file metadata entries.
  patch(type_at - 4 - 6 - 4, std::int32_t{1 << 30});
  expect_refused(bad, "grid count 1073741824");
  // File metadata follow the magic, versions, offsets flag and uuid (8 + 4 + 8 + 1 + 36).
  patch(57, std::uint32_t{1u << 31});
  expect_refused(bad, "file metadata claims 2147483648 entries");
  // Not VDB at all; an unknown version.
  patch(0, std::int64_t{0x1234});
  expect_refused(bad, "not a .vdb file");
  patch(8, std::uint32_t{999});
  expect_refused(bad, "unsupported .vdb file format version 999");
}

TEST_F(VdbValidate, HostileTreeCountsAndChunkSizesAreRefused) {
  const Sample s = small_file(dir_);
  const VdbFileCheck ok = validate_vdb_file(s.path, registered);
  ASSERT_EQ(ok.grids.size(), 1u);
  // Find the root's tile and child counts: right after the transform, the buffer
  // count (1) and the background (0.0f) precede them.
  const std::ptrdiff_t map_at = find(s.bytes, "ScaleTranslateMap");
  const std::ptrdiff_t map_name_at = map_at >= 0 ? map_at : find(s.bytes, "UniformScaleMap");
  ASSERT_GE(map_name_at, 0);
  const std::size_t map_len = map_at >= 0 ? 17 : 15;
  const std::ptrdiff_t counts_at =
      map_name_at + static_cast<std::ptrdiff_t>(map_len) + (map_at >= 0 ? 144 : 120) + 4 + 4;
  std::uint32_t tiles = 0, children = 0;
  std::memcpy(&tiles, s.bytes.data() + counts_at, 4);
  std::memcpy(&children, s.bytes.data() + counts_at + 4, 4);
  ASSERT_EQ(tiles, 0u);
  ASSERT_GE(children, 1u);
  const auto bad = dir_ / "bad.vdb";
  std::vector<char> b = s.bytes;
  const std::uint32_t huge = 4000000000u;
  std::memcpy(b.data() + counts_at + 4, &huge, 4);
  write_all(bad, b);
  expect_refused(bad, "the root claims 0 tiles and 4000000000 children");
  // The first leaf buffer's chunk: after the topology (block position), a 64-byte
  // value mask and the node's compression flag, then the int64 chunk size.
  const std::ptrdiff_t type_at = find(s.bytes, "Tree_float_5_4_3");
  std::int64_t block_pos = 0;
  std::memcpy(&block_pos, s.bytes.data() + type_at + 16 + 4 + 8, 8);
  const std::ptrdiff_t chunk_at = block_pos + 64 + 1;
  b = s.bytes;
  const std::int64_t claimed = std::int64_t{1} << 40;
  std::memcpy(b.data() + chunk_at, &claimed, 8);
  write_all(bad, b);
  expect_refused(bad, "chunk needs 1099511627776 bytes");
  b = s.bytes;
  const std::int64_t raw = -(std::int64_t{1} << 20);  // "uncompressed" but not 512 floats
  std::memcpy(b.data() + chunk_at, &raw, 8);
  write_all(bad, b);
  expect_refused(bad, "an uncompressed chunk of 1048576 bytes");
}

// Every single-byte corruption of the header and topology is either refused by the
// walk or read by OpenVDB (through inspect_vdb: the walk, then the guarded read)
// into a grid or a clean InputError: never a crash or a runaway allocation.
TEST_F(VdbValidate, EverySingleByteCorruptionOfTheHeaderIsCaught) {
  const Sample s = small_file(dir_);
  const std::ptrdiff_t type_at = find(s.bytes, "Tree_float_5_4_3");
  std::int64_t block_pos = 0;
  std::memcpy(&block_pos, s.bytes.data() + type_at + 16 + 4 + 8, 8);
  const auto bad = dir_ / "bad.vdb";
  int refused = 0, read = 0;
  // Every byte of the header, metadata, descriptor and transform; then every 61st
  // byte of the topology and the first leaf buffers (a full sweep takes minutes).
  const std::ptrdiff_t end = std::min<std::ptrdiff_t>(block_pos + 200, static_cast<std::ptrdiff_t>(s.bytes.size()));
  for (std::ptrdiff_t at = 0; at < end; at += at < 800 ? 1 : 61) {
    for (const unsigned char x : {0x01, 0xFF}) {
      std::vector<char> b = s.bytes;
      b[static_cast<std::size_t>(at)] = static_cast<char>(b[static_cast<std::size_t>(at)] ^ x);
      write_all(bad, b);
      try {
        (void)validate_vdb_file(bad, registered);
      } catch (const InputError&) {
        ++refused;
        continue;
      }
      ++read;
      try {
        (void)inspect_vdb(bad);
      } catch (const InputError& e) {
        EXPECT_EQ(std::string(e.what()).find('\n'), std::string::npos) << e.what();
      }
    }
  }
  EXPECT_GT(refused, 0);
  EXPECT_GT(read, 0);  // payload-like bytes (uuid digits, metadata values) still read
}

}  // namespace
}  // namespace hisnegs::io
