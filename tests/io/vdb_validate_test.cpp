// SPDX-License-Identifier: Apache-2.0
// Tests of io/vdb_validate: every file OpenVDB writes (value types, maps, half
// floats, compressions, instances, metadata types, points) passes the walk, which
// lands exactly on each descriptor's block and end positions; truncations and the
// hostile numbers OpenVDB would trust (string lengths, counts, chunk sizes) are
// refused with one line; and any single-byte corruption either is refused or reads
// through OpenVDB as a clean InputError or a grid.
#include "io/vdb_validate.hpp"

#include <gtest/gtest.h>
#include <openvdb/io/File.h>
#include <openvdb/openvdb.h>
#include <openvdb/points/PointConversion.h>

#include <cstring>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "io/error.hpp"
#include "io/sparse_grid.hpp"
#include "io/vdb_file.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {

using Depth = VdbGridCheck::Depth;

bool registered(const std::string& type) { return openvdb::Metadata::isRegisteredType(type); }

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

template <class GridT>
typename GridT::Ptr sphere_of(typename GridT::ValueType value, int radius = 12) {
  auto g = GridT::create();
  auto acc = g->getAccessor();
  for (int x = -radius; x <= radius; ++x)
    for (int y = -radius; y <= radius; ++y)
      for (int z = -radius; z <= radius; z += 2)
        if (x * x + y * y + z * z <= radius * radius) acc.setValue(openvdb::Coord(x + 3, y, z), value);
  return g;
}

void write_file(const std::filesystem::path& p, const openvdb::GridPtrVec& grids, std::uint32_t compression,
                const openvdb::MetaMap& file_meta = {}) {
  openvdb::io::File f(p.string());
  f.setCompression(compression);
  f.write(grids, file_meta);
  f.close();
}

class VdbValidate : public ::testing::Test {
 protected:
  void SetUp() override { ensure_openvdb_initialized(); }
  testing::ScratchDir dir_;
};

TEST_F(VdbValidate, EveryValueTypeMapAndCompressionWalksToItsEnd) {
  using namespace openvdb;
  auto f = sphere_of<FloatGrid>(0.5f);
  f->setName("float");
  f->setTransform(math::Transform::createLinearTransform(0.25));
  auto d = sphere_of<DoubleGrid>(2.0);
  d->setName("double");
  d->setTransform(math::Transform::createLinearTransform(math::Mat4d::identity()));
  d->transform().postRotate(0.3, math::Y_AXIS);  // an affine map
  auto v = sphere_of<Vec3SGrid>(Vec3s(1, 2, 3));
  v->setName("vec3s");
  v->setTransform(math::Transform::Ptr(new math::Transform(
      math::MapBase::Ptr(new math::ScaleTranslateMap(Vec3d(1, 2, 3), Vec3d(0.5, 0, -1))))));
  auto i = sphere_of<Int32Grid>(7);
  i->setName("int32");
  i->setTransform(math::Transform::Ptr(new math::Transform(math::MapBase::Ptr(new math::TranslationMap(Vec3d(1, 2, 3))))));
  auto b = sphere_of<BoolGrid>(true);
  b->setName("bool");
  auto m = MaskGrid::create();
  m->topologyUnion(*f);
  m->setName("mask");
  auto h = sphere_of<FloatGrid>(0.25f, 9);
  h->setName("half");
  h->setSaveFloatAsHalf(true);
  h->setTransform(math::Transform::createFrustumTransform(BBoxd(Vec3d(0), Vec3d(10)), 0.5, 2.0, 0.1));
  auto inst = f->copyGrid();  // shares f's tree: written as an instance
  inst->setName("instance");
  MetaMap file_meta;
  file_meta.insertMeta("note", StringMetadata("a file-level string"));
  file_meta.insertMeta("count", Int64Metadata(3));
  file_meta.insertMeta("origin", Vec3DMetadata(Vec3d(1, 2, 3)));
  file_meta.insertMeta("m", Mat4DMetadata(math::Mat4d::identity()));
  const GridPtrVec grids{f, d, v, i, b, m, h, inst};
  for (const std::uint32_t c : std::initializer_list<std::uint32_t>{openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK, openvdb::io::COMPRESS_ZIP | openvdb::io::COMPRESS_ACTIVE_MASK,
                                openvdb::io::COMPRESS_ACTIVE_MASK, openvdb::io::COMPRESS_NONE, openvdb::io::COMPRESS_BLOSC}) {
    SCOPED_TRACE("compression " + std::to_string(c));
    const auto path = dir_ / ("all" + std::to_string(c) + ".vdb");
    write_file(path, grids, c, file_meta);
    const VdbFileCheck check = validate_vdb_file(path, registered);
    EXPECT_EQ(check.file_version, std::uint32_t{OPENVDB_FILE_VERSION});
    ASSERT_EQ(check.grids.size(), grids.size());
    for (const VdbGridCheck& g : check.grids) {
      SCOPED_TRACE(g.name);
      if (g.name == "bool" || g.name == "mask") {
        EXPECT_EQ(g.depth, Depth::kTopology);
      } else if (g.name == "instance") {
        EXPECT_TRUE(g.instance);
      } else {
        EXPECT_EQ(g.depth, Depth::kBuffers);
      }
      if (!g.instance) EXPECT_GT(g.leaves, 0);
    }
    EXPECT_TRUE(check.grids[6].half_float);
    EXPECT_EQ(check.grids[0].leaves, static_cast<std::int64_t>(f->tree().leafCount()));
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

  using namespace openvdb;
  const std::vector<Vec3R> positions{{0, 0, 0}, {1.5, 2, 3}, {-4, 8, 1}, {30, 1, -7}};
  const auto xform = math::Transform::createLinearTransform(0.5);
  auto points = points::createPointDataGrid<points::NullCodec, points::PointDataGrid>(positions, *xform);
  points->setName("points");
  const auto ppath = dir_ / "points.vdb";
  write_file(ppath, GridPtrVec{points}, openvdb::io::COMPRESS_BLOSC | openvdb::io::COMPRESS_ACTIVE_MASK);
  const VdbFileCheck pcheck = validate_vdb_file(ppath, registered);
  ASSERT_EQ(pcheck.grids.size(), 1u);
  EXPECT_EQ(pcheck.grids[0].depth, Depth::kTopology);  // attribute buffers are OpenVDB's own format
  EXPECT_EQ(pcheck.grids[0].leaves, static_cast<std::int64_t>(points->tree().leafCount()));
}

// A small hisnegs .vdb and its bytes, for the corruption tests.
struct Sample {
  std::filesystem::path path;
  std::vector<char> bytes;
};

Sample small_file(const testing::ScratchDir& dir) {
  auto g = sphere_of<openvdb::FloatGrid>(0.75f, 6);
  g->setName("volume");
  g->insertMeta("source", openvdb::StringMetadata("a.tif"));
  Sample s{dir / "small.vdb", {}};
  write_vdb_file(s.path, openvdb::GridPtrVec{g});
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
  patch(type_at - 4 - 6 - 4 - 4, std::uint32_t{1u << 31});
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
  const std::ptrdiff_t counts_at = map_name_at + static_cast<std::ptrdiff_t>(map_len) + (map_at >= 0 ? 144 : 120) + 4 + 4;
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
