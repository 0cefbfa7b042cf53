// SPDX-License-Identifier: Apache-2.0
// io/zarr_stack: OME-Zarr and Zarr arrays written by independent writers
// (tests/io/zarr_fixtures.py: zarr-python for v2, chunks encoded by numcodecs /
// zlib / gzip and laid out by hand for v3 and sharding) read back whole and by
// region with their spacing; what is refused is refused in one line; region reads
// decode only the chunks they meet; the pyramid hisnegs writes is read back by
// zarr-python and by the reader.
#include "io/zarr_stack.hpp"

#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cstdlib>
#include <thread>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>

#include "io/error.hpp"
#include "io/stack_file.hpp"
#include "io/volume_source.hpp"
#include "io/zarr_codecs.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {
namespace fs = std::filesystem;
using hisnegs::testing::ScratchDir;

bool have_zarr_python() { return std::system("/usr/bin/python3 -c 'import zarr, numcodecs, numpy' 2>/dev/null") == 0; }

#define REQUIRE_ZARR_PYTHON()                                                                          \
  do {                                                                                                 \
    if (!have_zarr_python()) {                                                                         \
      if (std::getenv("CI")) FAIL() << "python3-zarr is missing; scripts/install-deps.sh installs it"; \
      GTEST_SKIP() << "python3 with zarr is not installed";                                            \
    }                                                                                                  \
  } while (0)

// A folder of this process for the fixtures, apart from every test's ScratchDir
// (which is named after the running test: under ctest, one test per process, the
// first test's ScratchDir would be this very folder and wipe it).
class FixtureDir {
 public:
  FixtureDir() : path_(fs::temp_directory_path() / ("hisnegs-zarr-fixtures-" + std::to_string(::getpid()))) {
    fs::remove_all(path_);
    fs::create_directories(path_);
  }
  ~FixtureDir() {
    std::error_code ec;
    fs::remove_all(path_, ec);
  }
  FixtureDir(const FixtureDir&) = delete;
  FixtureDir& operator=(const FixtureDir&) = delete;
  [[nodiscard]] const fs::path& path() const { return path_; }

 private:
  fs::path path_;
};

// The fixtures, written once per test binary.
const fs::path& zarr_fixtures() {
  static FixtureDir dir;
  static const bool made = [] {
    const auto r = hisnegs::testing::run_shell(
        "/usr/bin/python3 " + hisnegs::testing::shell_quoted(hisnegs::testing::source_dir() / "tests/io/zarr_fixtures.py") +
        " " + hisnegs::testing::shell_quoted(dir.path()) + " 2>&1");
    EXPECT_EQ(r.status, 0) << r.out;
    return r.status == 0;
  }();
  (void)made;
  return dir.path();
}

StackReadOptions zarr_options(const nlohmann::json& o) {
  StackReadOptions s;
  if (o.contains("channel")) s.tiff.channel = o["channel"].get<int>();
  if (o.contains("timepoint")) s.timepoint = o["timepoint"].get<int>();
  s.level = o.value("level", 0);
  return s;
}

std::vector<float> zarr_values(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  std::vector<float> v(fs::file_size(file) / sizeof(float));
  in.read(reinterpret_cast<char*>(v.data()), static_cast<std::streamsize>(v.size() * sizeof(float)));
  return v;
}

std::string zarr_error(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "(no InputError)";
}

TEST(ZarrStack, EveryFixtureReadsWholeAndByRegionWithItsSpacing) {
  REQUIRE_ZARR_PYTHON();
  const fs::path& dir = zarr_fixtures();
  const nlohmann::json manifest = nlohmann::json::parse(std::ifstream(dir / "manifest.json"));
  ASSERT_GT(manifest.size(), 60u);
  std::mt19937 rng(3);
  int read = 0;
  for (const auto& f : manifest) {
    SCOPED_TRACE(f["name"].get<std::string>());
    const fs::path path = dir / f["path"].get<std::string>();
    const StackReadOptions options = zarr_options(f["options"]);
    if (f.contains("error")) {
      const std::string e = zarr_error([&] { (void)read_stack(path, options); });
      EXPECT_NE(e.find(f["error"].get<std::string>()), std::string::npos) << e;
      EXPECT_EQ(e.find('\n'), std::string::npos) << e;
      continue;
    }
    const StackHeader h = inspect_stack(path, options);
    const std::array<int, 3> shape{h.nx, h.ny, h.nz};
    const auto stated = f["shape"].get<std::array<int, 3>>();
    ASSERT_EQ(shape, stated) << h.format;
    for (int a = 0; a < 3; ++a) EXPECT_NEAR(h.spacing.um[a], f["spacing"][a].get<double>(), 1e-9) << a;
    const std::vector<float> expected = zarr_values(dir / f["values"].get<std::string>());
    const Volume v = read_stack(path, options);
    ASSERT_EQ(v.voxels.size(), expected.size());
    EXPECT_EQ(v.voxels, expected) << h.format;
    // A region across chunk borders, through the VolumeSource.
    const auto source = open_volume_source(path, options);
    EXPECT_EQ(source->format, h.format);
    VoxelBox box;
    const std::array<int, 3> n{h.nx, h.ny, h.nz};
    for (int a = 0; a < 3; ++a) {
      box.lo[a] = std::uniform_int_distribution<int>(0, n[a] - 1)(rng);
      box.hi[a] = std::uniform_int_distribution<int>(box.lo[a] + 1, n[a])(rng);
    }
    std::vector<float> part(box.voxels());
    source->read(box, part.data());
    std::size_t i = 0, wrong = 0;
    for (int z = box.lo[2]; z < box.hi[2]; ++z) {
      for (int y = box.lo[1]; y < box.hi[1]; ++y) {
        for (int x = box.lo[0]; x < box.hi[0]; ++x, ++i) {
          wrong += part[i] != expected[(static_cast<std::size_t>(z) * h.ny + y) * h.nx + x] ? 1 : 0;
        }
      }
    }
    EXPECT_EQ(wrong, 0u);
    ++read;
  }
  EXPECT_GT(read, 50);
}

// Four threads reading random boxes of one source at once (a sharded v3 array and a
// v2 array): each box equals the same part of the whole read.
TEST(ZarrStack, ConcurrentRegionReadsAgreeWithTheWholeRead) {
  REQUIRE_ZARR_PYTHON();
  for (const char* name : {"v3-shard-start.zarr", "v2-blosc-zstd-1-slash.zarr"}) {
    SCOPED_TRACE(name);
    const auto source = open_volume_source(zarr_fixtures() / name);
    const Volume whole = read_stack(zarr_fixtures() / name);
    std::atomic<int> wrong{0};
    std::vector<std::thread> threads;
    threads.reserve(4);
    for (int t = 0; t < 4; ++t) {
      threads.emplace_back([&, t] {
        std::mt19937 rng(static_cast<unsigned>(t));
        const std::array<int, 3> n{source->nx, source->ny, source->nz};
        for (int k = 0; k < 50; ++k) {
          VoxelBox box;
          for (int a = 0; a < 3; ++a) {
            box.lo[a] = std::uniform_int_distribution<int>(0, n[a] - 1)(rng);
            box.hi[a] = std::uniform_int_distribution<int>(box.lo[a] + 1, n[a])(rng);
          }
          std::vector<float> part(box.voxels());
          source->read(box, part.data());
          std::size_t i = 0;
          for (int z = box.lo[2]; z < box.hi[2]; ++z) {
            for (int y = box.lo[1]; y < box.hi[1]; ++y) {
              for (int x = box.lo[0]; x < box.hi[0]; ++x, ++i) wrong += part[i] != whole.voxels[whole.index(x, y, z)] ? 1 : 0;
            }
          }
        }
      });
    }
    for (std::thread& t : threads) t.join();
    EXPECT_EQ(wrong.load(), 0);
  }
}

TEST(ZarrStack, DescribesTheFormatLevelAndCodecs) {
  REQUIRE_ZARR_PYTHON();
  ZarrReadOptions channel_1;
  channel_1.channel = 1;
  const ZarrStackInfo info = inspect_zarr_stack(zarr_fixtures() / "ome05.ome.zarr", channel_1);
  EXPECT_EQ(info.describe(),
            "OME-Zarr v0.5 (Zarr v3), level 0 of 2, uint8, axes czyx, chunks 1x4x8x8, sharding(inner 1x4x8x8; gzip), 2 channels");
  ASSERT_EQ(info.pyramid.size(), 2u);
  EXPECT_EQ(info.pyramid[1].shape, (std::vector<long long>{2, 12, 16, 16}));
  EXPECT_DOUBLE_EQ(info.pyramid[1].scale_um[0], 0.8);
  EXPECT_EQ(info.spacing.source[0], SpacingSource::kOmeZarr);
}

TEST(ZarrStack, ARegionReadDecodesOnlyTheChunksItMeets) {
  REQUIRE_ZARR_PYTHON();
  ScratchDir dir;
  // A copy of a v2 array and a sharded v3 array, with one chunk (inner chunk) damaged.
  for (const char* name : {"v2-zstd-slash.zarr", "v3-shard-end.zarr"}) {
    fs::copy(zarr_fixtures() / name, dir / name, fs::copy_options::recursive);
  }
  // v2, chunks 4x8x16 (z, y, x): chunk 1/1/1 holds z 4..8, y 8..16, x 16..32.
  {
    std::ofstream(dir / "v2-zstd-slash.zarr/1/1/1", std::ios::binary | std::ios::trunc) << "not zstd";
    const auto s = open_volume_source(dir / "v2-zstd-slash.zarr");
    std::vector<float> out(4 * 8 * 16);
    EXPECT_NO_THROW(s->read({{0, 0, 0}, {16, 8, 4}}, out.data()));
    const std::string e = zarr_error([&] { s->read({{15, 7, 3}, {17, 9, 5}}, out.data()); });
    EXPECT_EQ(e.rfind((dir / "v2-zstd-slash.zarr/1/1/1").string() + ": zstd", 0), 0u) << e;
  }
  // v3 shard c/0/0/0 (8x16x16), inner chunks 4x8x8: damage the bytes of inner chunk 0 only.
  {
    const fs::path shard = dir / "v3-shard-end.zarr/c/0/0/0";
    std::fstream f(shard, std::ios::binary | std::ios::in | std::ios::out);
    f.seekp(8);
    f.write("XXXXXXXX", 8);
    f.close();
    const auto s = open_volume_source(dir / "v3-shard-end.zarr");
    std::vector<float> out(4 * 8 * 8);
    EXPECT_NO_THROW(s->read({{8, 8, 4}, {16, 16, 8}}, out.data()));  // inner chunk (1, 1, 1)
    const std::string e = zarr_error([&] { s->read({{0, 0, 0}, {2, 2, 2}}, out.data()); });
    EXPECT_EQ(e.rfind(shard.string() + ": blosc", 0), 0u) << e;
  }
}

TEST(ZarrStack, ACorruptShardIndexOrATruncatedShardIsNamed) {
  REQUIRE_ZARR_PYTHON();
  ScratchDir dir;
  fs::copy(zarr_fixtures() / "v3-shard-end.zarr", dir / "s.zarr", fs::copy_options::recursive);
  const fs::path shard = dir / "s.zarr/c/0/0/0";
  const auto size = fs::file_size(shard);
  {
    std::fstream f(shard, std::ios::binary | std::ios::in | std::ios::out);
    f.seekp(static_cast<std::streamoff>(size - 10));
    f.write("\x7f", 1);
  }
  const auto s = open_volume_source(dir / "s.zarr");
  std::vector<float> out(8);
  EXPECT_EQ(zarr_error([&] { s->read({{0, 0, 0}, {2, 2, 2}}, out.data()); }), shard.string() + ": shard index: crc32c: checksum mismatch");
  fs::resize_file(shard, 20);
  EXPECT_NE(zarr_error([&] { s->read({{0, 0, 0}, {2, 2, 2}}, out.data()); }).find("shorter than its shard index"),
            std::string::npos);
}

TEST(ZarrStack, AFifoInPlaceOfAChunkIsRefusedNotWaitedOn) {
  REQUIRE_ZARR_PYTHON();
  ScratchDir dir;
  fs::copy(zarr_fixtures() / "v2-none-dot.zarr", dir / "a.zarr", fs::copy_options::recursive);
  fs::remove(dir / "a.zarr/0.0.0");
  ASSERT_EQ(::mkfifo((dir / "a.zarr/0.0.0").c_str(), 0600), 0);
  const auto s = open_volume_source(dir / "a.zarr");
  std::vector<float> out(1);
  EXPECT_NE(zarr_error([&] { s->read({{0, 0, 0}, {1, 1, 1}}, out.data()); }).find("not a regular file"), std::string::npos);
}

TEST(ZarrStack, TheIdentityChangesWithAnyChunkAndHoldsWhatIsInside) {
  REQUIRE_ZARR_PYTHON();
  ScratchDir dir;
  fs::copy(zarr_fixtures() / "v2-zlib-slash.zarr", dir / "a.zarr", fs::copy_options::recursive);
  const StackIdentity id = stack_identity(dir / "a.zarr");
  const std::string before = id.content();
  EXPECT_EQ(before, id.content());
  EXPECT_TRUE(id.holds(dir / "a.zarr/1/1/1"));
  EXPECT_TRUE(id.holds(dir / "a.zarr/new-file"));
  EXPECT_FALSE(id.holds(dir / "b.zarr"));
  std::ofstream(dir / "a.zarr/1/1/1", std::ios::app) << "x";
  EXPECT_NE(before, id.content());
}

TEST(ZarrStack, OptionsThatDoNotApplyAreRefusedInOneLine) {
  REQUIRE_ZARR_PYTHON();
  StackReadOptions o;
  o.dataset = "/data";
  EXPECT_NE(zarr_error([&] { (void)inspect_stack(zarr_fixtures() / "v2-none-dot.zarr", o); }).find("--dataset"), std::string::npos);
  StackReadOptions level;
  level.level = 1;
  EXPECT_NE(zarr_error([&] { (void)inspect_stack(zarr_fixtures() / "v2-none-dot.zarr", level); }).find("--level 1"),
            std::string::npos);
}

TEST(ZarrCodecs, RoundTripEveryCodecAndKnowTheCrc32cCheckValue) {
  const std::string check = "123456789";
  EXPECT_EQ(zarr::crc32c(std::span(reinterpret_cast<const std::uint8_t*>(check.data()), check.size())), 0xE3069283u);
  std::vector<std::uint8_t> data(10000);
  std::mt19937 rng(1);
  for (auto& b : data) b = static_cast<std::uint8_t>(rng() % 7);
  using K = zarr::ByteCodec::Kind;
  for (const K kind : {K::kBlosc, K::kZlib, K::kGzip, K::kZstd, K::kCrc32c}) {
    zarr::ByteCodec c;
    c.kind = kind;
    const auto packed = zarr::encode(c, data);
    const std::size_t expected = data.size();
    EXPECT_EQ(zarr::decode(c, packed, expected), data) << c.name();
    EXPECT_THROW((void)zarr::decode(c, packed, expected + 1), std::runtime_error) << c.name();
  }
}

TEST(ZarrWrite, APyramidReadsBackHereAndInZarrPython) {
  REQUIRE_ZARR_PYTHON();
  ScratchDir dir;
  Volume v;
  v.nx = 150, v.ny = 131, v.nz = 9;
  v.spacing.um = {0.5, 0.5, 2.0};
  v.voxels.resize(v.size());
  std::mt19937 rng(5);
  for (float& x : v.voxels) x = std::uniform_real_distribution<float>(0.0f, 1.0f)(rng);
  const fs::path out = dir / "m.ome.zarr";
  ZarrWriteOptions small_levels;
  small_levels.min_edge = 32;
  write_ome_zarr(out, v, small_levels);
  const ZarrStackInfo info = inspect_zarr_stack(out);
  EXPECT_EQ(info.ome_version, "0.4");
  ASSERT_EQ(info.pyramid.size(), 3u);  // 150 -> 75 -> 38 (the next, 19, is under 32)
  EXPECT_EQ(info.pyramid[1].shape, (std::vector<long long>{9, 66, 75}));  // z kept: 2 um is coarser than 1 um
  EXPECT_DOUBLE_EQ(info.pyramid[2].scale_um[0], 2.0);
  EXPECT_DOUBLE_EQ(info.pyramid[2].scale_um[2], 2.0);  // z kept again: x, y reach its 2 um
  EXPECT_EQ(read_stack(out).voxels, v.voxels);
  const Volume l1 = read_stack(out, [] { StackReadOptions o; o.level = 1; return o; }());
  EXPECT_NEAR(l1.voxels[l1.index(3, 4, 5)],
              (v.voxels[v.index(6, 8, 5)] + v.voxels[v.index(7, 8, 5)] + v.voxels[v.index(6, 9, 5)] +
               v.voxels[v.index(7, 9, 5)]) / 4.0f, 1e-6f);
  EXPECT_DOUBLE_EQ(l1.spacing.um[0], 1.0);
  // zarr-python reads every level, its attributes and the values.
  std::ofstream(dir / "read.py") << "import zarr, numpy as np\n"
                                    "g = zarr.open_group('m.ome.zarr', mode='r')\n"
                                    "ms = g.attrs['multiscales'][0]\n"
                                    "assert ms['version'] == '0.4' and [a['name'] for a in ms['axes']] == ['z', 'y', 'x']\n"
                                    "a = g['0'][:]\n"
                                    "assert a.shape == (9, 131, 150) and a.dtype == np.float32\n"
                                    "b = np.fromfile('v.f32', dtype=np.float32).reshape(9, 131, 150)\n"
                                    "assert (a == b).all()\n"
                                    "print([g[d['path']].shape for d in ms['datasets']])\n";
  std::ofstream(dir / "v.f32", std::ios::binary)
      .write(reinterpret_cast<const char*>(v.voxels.data()), static_cast<std::streamsize>(v.voxels.size() * 4));
  const auto r = hisnegs::testing::run_shell("cd " + hisnegs::testing::shell_quoted(dir.path()) + " && /usr/bin/python3 read.py 2>&1");
  EXPECT_EQ(r.status, 0) << r.out;
  EXPECT_NE(r.out.find("[(9, 131, 150), (9, 66, 75), (9, 33, 38)]"), std::string::npos) << r.out;
  // Writing again replaces the store; a folder that is not one is refused.
  write_ome_zarr(out, v, small_levels);
  fs::create_directories(dir / "other");
  EXPECT_NE(zarr_error([&] { write_ome_zarr(dir / "other", v); }).find("not a Zarr folder"), std::string::npos);
  EXPECT_EQ(dir.entries().size(), 4u);  // m.ome.zarr, other, read.py, v.f32 and nothing half-written
}

}  // namespace
}  // namespace hisnegs::io
