// SPDX-License-Identifier: Apache-2.0
// io/hdf5_stack and io/stack_file: plain HDF5 stacks written by hisnegs and read
// back (whole and by region), BigDataViewer and Imaris files written by h5py (an
// independent writer: Debian's python3-h5py) read with their spacing, and every
// bad input of issue 34's list that is about HDF5 refused in one line naming the file.
#include "io/hdf5_stack.hpp"

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "io/error.hpp"
#include "io/stack_file.hpp"
#include "io/volume_source.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {
namespace fs = std::filesystem;
using hisnegs::testing::ScratchDir;

Volume random_volume(int nx, int ny, int nz, float top, std::uint64_t seed) {
  Volume v;
  v.nx = nx, v.ny = ny, v.nz = nz;
  v.voxels.resize(v.size());
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> u(0, static_cast<int>(top));
  for (float& x : v.voxels) x = static_cast<float>(u(rng));
  v.spacing.um = {0.25, 0.5, 2.0};
  return v;
}

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "(no InputError)";
}

TEST(Hdf5Stack, PlainRoundTripsEveryTypeWholeAndByRegion) {
  ScratchDir dir;
  for (const SampleType type : {SampleType::kUint8, SampleType::kUint16, SampleType::kFloat32}) {
    const Volume v = random_volume(37, 29, 11, type == SampleType::kUint8 ? 255.f : 60000.f, 3);
    const fs::path path = dir / ("s" + std::string(to_string(type)) + ".h5");
    write_hdf5_stack(path, v, {.dataset = "/g/data", .type = type, .chunk_zyx = {4, 8, 16}, .gzip_level = 3});
    ASSERT_TRUE(is_hdf5_stack(path));
    const Volume back = read_stack(path);
    EXPECT_EQ(back.nx, 37);
    EXPECT_EQ(back.ny, 29);
    EXPECT_EQ(back.nz, 11);
    EXPECT_EQ(back.stored_as, type);
    EXPECT_EQ(back.voxels, v.voxels);
    EXPECT_EQ(back.spacing.um, v.spacing.um) << "element_size_um (z, y, x)";
    EXPECT_EQ(back.spacing.source[2], SpacingSource::kHdf5);
    const Hdf5StackInfo info = inspect_hdf5_stack(path);
    EXPECT_EQ(info.dataset, "/g/data");
    EXPECT_EQ(info.describe(), "HDF5, g/data 11x29x37, " + std::string(to_string(type)) + ", chunks 4x8x16, gzip");
    // Regions, including ones that cut chunks, equal the same voxels of the whole.
    std::mt19937 rng(7);
    for (int k = 0; k < 20; ++k) {
      std::array<int, 3> lo{}, hi{};
      const std::array<int, 3> n{37, 29, 11};
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::uniform_int_distribution<int>(0, n[a] - 1)(rng);
        hi[a] = std::uniform_int_distribution<int>(lo[a] + 1, n[a])(rng);
      }
      std::vector<float> region(static_cast<std::size_t>(hi[0] - lo[0]) * (hi[1] - lo[1]) * (hi[2] - lo[2]));
      read_hdf5_region(info, lo, hi, region.data());
      std::size_t i = 0;
      for (int z = lo[2]; z < hi[2]; ++z)
        for (int y = lo[1]; y < hi[1]; ++y)
          for (int x = lo[0]; x < hi[0]; ++x) ASSERT_EQ(region[i++], v.at(x, y, z)) << x << "," << y << "," << z;
    }
  }
}

TEST(Hdf5Stack, TheOnlyStackIsFoundAndSeveralNeedDataset) {
  ScratchDir dir;
  const Volume v = random_volume(8, 6, 4, 255.f, 1);
  write_hdf5_stack(dir / "one.h5", v, {.dataset = "/deep/inside/stack", .type = SampleType::kUint8});
  EXPECT_EQ(read_stack(dir / "one.h5").voxels, v.voxels);
  StackReadOptions named;
  named.dataset = "deep/inside/stack";  // without the leading slash
  EXPECT_EQ(read_stack(dir / "one.h5", named).voxels, v.voxels);
  named.dataset = "/nope";
  EXPECT_EQ(error_of([&] { (void)read_stack(dir / "one.h5", named); }), (dir / "one.h5").string() + ": has no dataset /nope");
  named.dataset = "/deep";
  EXPECT_EQ(error_of([&] { (void)read_stack(dir / "one.h5", named); }), (dir / "one.h5").string() + ": /deep is not a dataset");
}

TEST(Hdf5Stack, TiffRefusesHdf5OnlyOptions) {
  ScratchDir dir;
  const Volume v = random_volume(8, 6, 4, 255.f, 1);
  write_tiff_stack(dir / "s.tif", v.voxels, 8, 6, 4, {.type = SampleType::kUint8});
  StackReadOptions o;
  o.dataset = "/data";
  EXPECT_NE(error_of([&] { (void)read_stack(dir / "s.tif", o); }).find("--dataset is for HDF5 files"), std::string::npos);
  EXPECT_EQ(read_stack(dir / "s.tif").voxels, v.voxels);
}

// Truncated files and a file that is not HDF5 at all: one line naming the file.
TEST(Hdf5Stack, TruncatedFileIsOneLine) {
  ScratchDir dir;
  write_hdf5_stack(dir / "t.h5", random_volume(64, 64, 16, 60000.f, 2), {.chunk_zyx = {8, 32, 32}});
  const auto size = fs::file_size(dir / "t.h5");
  fs::resize_file(dir / "t.h5", size / 2);
  const std::string e = error_of([&] { (void)read_stack(dir / "t.h5"); });
  EXPECT_EQ(e.rfind((dir / "t.h5").string() + ": ", 0), 0u) << e;
  EXPECT_EQ(e.find('\n'), std::string::npos) << e;
}

// The h5py-written fixtures: skipped where Debian's python3-h5py is missing (CI installs it).
bool have_h5py() {
  if (std::system("/usr/bin/python3 -c 'import h5py, numpy' 2>/dev/null") == 0) return true;
  return false;
}

#define REQUIRE_H5PY()                                                                        \
  do {                                                                                        \
    if (!have_h5py()) {                                                                       \
      if (std::getenv("CI")) FAIL() << "python3-h5py is missing; scripts/install-deps.sh installs it"; \
      GTEST_SKIP() << "python3 with h5py is not installed";                                   \
    }                                                                                         \
  } while (0)

void run_python(const fs::path& dir, const std::string& script) {
  hisnegs::testing::write_text(dir / "make.py", script);
  const auto r = hisnegs::testing::run_shell("cd " + hisnegs::testing::shell_quoted(dir) + " && /usr/bin/python3 make.py");
  ASSERT_EQ(r.status, 0) << r.out;
}

// The voxel value the fixtures write at (x, y, z): distinct, and above 32767 in
// places (BigDataViewer's int16 must read back as uint16).
constexpr const char* kValues = "import numpy as np, h5py\n"
                                "def values(nz, ny, nx):\n"
                                "    z, y, x = np.meshgrid(np.arange(nz), np.arange(ny), np.arange(nx), indexing='ij')\n"
                                "    return ((x * 7 + y * 131 + z * 3001) % 65536).astype(np.uint16)\n";

float value_at(int x, int y, int z) { return static_cast<float>((x * 7 + y * 131 + z * 3001) % 65536); }

void expect_values(const Volume& v) {
  for (int z = 0; z < v.nz; ++z)
    for (int y = 0; y < v.ny; ++y)
      for (int x = 0; x < v.nx; ++x) ASSERT_EQ(v.at(x, y, z), value_at(x, y, z)) << x << "," << y << "," << z;
}

TEST(Hdf5Stack, BigDataViewerWithItsXmlSpacing) {
  REQUIRE_H5PY();
  ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(run_python(dir.path(), std::string(kValues) + R"(
with h5py.File('bdv.h5', 'w') as f:
    for s in (0, 1):
        f['s%02d/resolutions' % s] = np.array([[1, 1, 1], [2, 2, 2]], dtype='f8')
        f['s%02d/subdivisions' % s] = np.array([[16, 16, 8], [16, 16, 8]], dtype='i4')
        for t in (0,):
            d = values(12, 20, 24).view(np.int16)
            f.create_dataset('t%05d/s%02d/0/cells' % (t, s), data=d, chunks=(8, 16, 16), compression='gzip')
            f.create_dataset('t%05d/s%02d/1/cells' % (t, s), data=d[::2, ::2, ::2], chunks=(4, 8, 8))
    f.create_group('s0x')  # not a setup
open('bdv.xml', 'w').write('''<?xml version="1.0" encoding="UTF-8"?>
<SpimData version="0.2"><BasePath type="relative">.</BasePath><SequenceDescription>
<ImageLoader format="bdv.hdf5"><hdf5 type="relative">bdv.h5</hdf5></ImageLoader>
<ViewSetups>
<ViewSetup><id>0</id><name>0</name><size>24 20 12</size><voxelSize><unit>nm</unit><size>300 300 1200</size></voxelSize></ViewSetup>
<ViewSetup><id>1</id><name>1</name><size>24 20 12</size><voxelSize><unit>um</unit><size>0.5 0.5 2</size></voxelSize></ViewSetup>
</ViewSetups><Timepoints type="range"><first>0</first><last>0</last></Timepoints></SequenceDescription></SpimData>
''')
)"));
  const fs::path xml = dir / "bdv.xml";
  ASSERT_TRUE(is_hdf5_stack(xml));
  EXPECT_NE(error_of([&] { (void)read_stack(xml); }).find("holds 2 setups: choose one with --channel (0..1)"),
            std::string::npos);
  StackReadOptions o;
  o.tiff.channel = 1;
  const Volume v = read_stack(xml, o);
  EXPECT_EQ(v.nx, 24);
  EXPECT_EQ(v.ny, 20);
  EXPECT_EQ(v.nz, 12);
  EXPECT_EQ(v.stored_as, SampleType::kUint16);
  EXPECT_EQ(v.spacing.um, (std::array<double, 3>{0.5, 0.5, 2.0}));
  expect_values(v);
  o.tiff.channel = 0;
  const Hdf5StackInfo info = inspect_hdf5_stack(xml, o.hdf5());
  EXPECT_NEAR(info.spacing.um[0], 0.3, 1e-12) << "nm -> um";
  EXPECT_NEAR(info.spacing.um[2], 1.2, 1e-12);
  EXPECT_EQ(info.describe(), "BigDataViewer HDF5, t00000/s00/0/cells 12x20x24, uint16 (stored as int16), chunks 8x16x16, "
                             "gzip, 2 channels");
  // The .h5 alone: the same data, the spacing from the .xml beside it.
  EXPECT_EQ(read_stack(dir / "bdv.h5", o).spacing.um[2], info.spacing.um[2]);
  // Both files count for caches, from either (the run's statistics and stage reuse).
  EXPECT_EQ(hdf5_stack_files(xml), (std::vector<fs::path>{xml, dir / "bdv.h5"}));
  EXPECT_EQ(hdf5_stack_files(dir / "bdv.h5"), (std::vector<fs::path>{dir / "bdv.h5", xml}));
  EXPECT_EQ(stack_files(xml), hdf5_stack_files(xml));
  EXPECT_EQ(stack_files(dir / "nothing.tif"), (std::vector<fs::path>{dir / "nothing.tif"}));
  // One identity for every fingerprint and input guard, the same the source opened
  // on the stack carries: both files; an output that is the .h5 behind the .xml is
  // held by it; a new .h5 behind an unchanged .xml changes its content.
  const StackIdentity identity = stack_identity(xml);
  EXPECT_EQ(identity.files, stack_files(xml));
  EXPECT_EQ(open_volume_source(xml, o)->identity.files, identity.files);
  EXPECT_TRUE(identity.holds(dir / "bdv.h5"));
  EXPECT_FALSE(identity.holds(dir / "nothing.tif"));
  const std::string before = identity.content();
  fs::copy_file(dir / "bdv.h5", dir / "copy.h5");
  fs::rename(dir / "copy.h5", dir / "bdv.h5");
  EXPECT_NE(stack_identity(xml).content(), before);
  EXPECT_TRUE(memory_source(Volume{})->identity.files.empty());
  // An .xml naming a folder: said so, not "does not exist".
  std::string text = testing::read_bytes(xml);
  text.replace(text.find(">bdv.h5<"), 8, ">.<");
  testing::write_text(dir / "folder.xml", text);
  EXPECT_NE(error_of([&] { (void)read_stack(dir / "folder.xml", o); }).find("which is not a regular file"),
            std::string::npos)
      << error_of([&] { (void)read_stack(dir / "folder.xml", o); });
}

TEST(Hdf5Stack, ImarisWithPaddedDataAndExtents) {
  REQUIRE_H5PY();
  ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(run_python(dir.path(), std::string(kValues) + R"(
def attr(obj, key, text):
    obj.attrs.create(key, np.array(list(text), dtype='S1'))
def make(name, with_extents):
    with h5py.File(name, 'w') as f:
        info = f.create_group('DataSetInfo/Image')
        for k, v in (('X', '30'), ('Y', '21'), ('Z', '9'), ('Unit', 'um')):
            attr(info, k, v)
        if with_extents:
            for k, v in (('ExtMin0', '-3'), ('ExtMax0', '12'), ('ExtMin1', '0'), ('ExtMax1', '10.5'),
                         ('ExtMin2', '5'), ('ExtMax2', '23')):
                attr(info, k, v)
        for c in (0, 1):
            g = f.create_group('DataSet/ResolutionLevel 0/TimePoint 0/Channel %d' % c)
            for k, v in (('ImageSizeX', '30'), ('ImageSizeY', '21'), ('ImageSizeZ', '9')):
                attr(g, k, v)
            padded = np.zeros((16, 32, 32), dtype=np.uint16)
            padded[:9, :21, :30] = values(9, 21, 30)
            g.create_dataset('Data', data=padded, chunks=(16, 32, 32), compression='gzip')
make('a.ims', True)
make('nospacing.ims', False)
)"));
  StackReadOptions o;
  o.tiff.channel = 1;
  const Volume v = read_stack(dir / "a.ims", o);
  EXPECT_EQ(v.nx, 30);
  EXPECT_EQ(v.ny, 21);
  EXPECT_EQ(v.nz, 9);
  EXPECT_NEAR(v.spacing.um[0], 0.5, 1e-12);  // (12 - -3) / 30
  EXPECT_NEAR(v.spacing.um[1], 0.5, 1e-12);
  EXPECT_NEAR(v.spacing.um[2], 2.0, 1e-12);
  expect_values(v);
  EXPECT_EQ(error_of([&] { (void)read_stack(dir / "nospacing.ims", o); }),
            (dir / "nospacing.ims").string() + ": /DataSetInfo/Image ExtMin0 is missing");
  // --spacing overrides what a file lacks.
  o.tiff.spacing_um = std::array<double, 3>{1.0, 1.0, 3.0};
  EXPECT_EQ(read_stack(dir / "nospacing.ims", o).spacing.um[2], 3.0);
}

TEST(Hdf5Stack, RanksTypesChunksAndFiltersAreChecked) {
  REQUIRE_H5PY();
  ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(run_python(dir.path(), std::string(kValues) + R"(
with h5py.File('ranks.h5', 'w') as f:
    f['czyx'] = np.stack([values(4, 5, 6), values(4, 5, 6) + 1])
    f['tczyx'] = np.zeros((3, 2, 4, 5, 6), dtype=np.uint8)
    f['flat'] = np.zeros((5, 6), dtype=np.uint8)
    f['f64'] = np.zeros((4, 5, 6), dtype='f8')
    f['plane'] = np.zeros((1, 5, 6), dtype=np.uint8)
    f['empty'] = np.zeros((0, 5, 6), dtype=np.uint8)
with h5py.File('missing.h5', 'w') as f:
    d = f.create_dataset('data', shape=(8, 16, 16), dtype=np.uint16, chunks=(4, 8, 8))
    d[:4] = 7  # the chunks of z 4..7 are never written
with h5py.File('filter.h5', 'w') as f:
    f.create_dataset('data', shape=(4, 8, 8), dtype=np.uint16, chunks=(4, 8, 8), compression=32001,
                     allow_unknown_filter=True)[...] = 1
)"));
  const fs::path ranks = dir / "ranks.h5";
  StackReadOptions o;
  o.dataset = "/czyx";
  EXPECT_NE(error_of([&] { (void)read_stack(ranks, o); }).find("holds 2 channels: choose one with --channel"),
            std::string::npos);
  o.tiff.channel = 1;
  const Volume c1 = read_stack(ranks, o);
  EXPECT_EQ(c1.voxels[0], 1.0f);
  EXPECT_EQ(c1.nx, 6);
  o.dataset = "/tczyx";
  EXPECT_NE(error_of([&] { (void)read_stack(ranks, o); }).find("holds 3 time points: choose one with --timepoint"),
            std::string::npos);
  o.timepoint = 2;
  EXPECT_EQ(read_stack(ranks, o).nz, 4);
  o.timepoint = 3;
  EXPECT_NE(error_of([&] { (void)read_stack(ranks, o); }).find("time point 3 does not exist"), std::string::npos);
  o = {};
  o.dataset = "/flat";
  EXPECT_NE(error_of([&] { (void)read_stack(ranks, o); }).find("is 5x6 (rank 2)"), std::string::npos);
  o.dataset = "/f64";
  EXPECT_NE(error_of([&] { (void)read_stack(ranks, o); }).find("holds float64 samples"), std::string::npos);
  o.dataset = "/plane";  // as a one-page TIFF is refused
  EXPECT_NE(error_of([&] { (void)read_stack(ranks, o); }).find("is 1x5x6: a single 2D image (1 plane)"),
            std::string::npos);
  o.dataset = "/empty";
  EXPECT_NE(error_of([&] { (void)read_stack(ranks, o); }).find("is 0x5x6: an empty axis"), std::string::npos);
  EXPECT_NE(error_of([&] { (void)read_stack(ranks); }).find("datasets that could be the stack"), std::string::npos);
  EXPECT_EQ(error_of([&] { (void)read_stack(dir / "missing.h5"); }),
            (dir / "missing.h5").string() +
                ": dataset /data: 4 of 8 chunks were never written (a missing chunk reads as the fill value, not data)");
  const std::string filter = error_of([&] { (void)read_stack(dir / "filter.h5"); });
  EXPECT_NE(filter.find("is compressed with filter 32001"), std::string::npos) << filter;
}

// External raw storage and virtual datasets read other files: read when each is a
// regular file beside the stack; refused when one is missing (a missing virtual
// source reads as zeros) or elsewhere (/etc/passwd as voxels).
TEST(Hdf5Stack, ExternalAndVirtualStorageOnlyFromFilesBesideTheStack) {
  REQUIRE_H5PY();
  ScratchDir dir;
  ASSERT_NO_FATAL_FAILURE(run_python(dir.path(), std::string(kValues) + R"(
import os
open('raw.bin', 'wb').write(bytes(range(120)))
with h5py.File('external.h5', 'w') as f:
    f.create_dataset('data', shape=(4, 5, 6), dtype='u1', external=[('raw.bin', 0, 120)])
with h5py.File('elsewhere.h5', 'w') as f:
    f.create_dataset('data', shape=(4, 5, 6), dtype='u1', external=[('/etc/passwd', 0, 120)])
with h5py.File('src.h5', 'w') as f:
    f['data'] = (np.arange(120) % 251).astype(np.uint8).reshape(4, 5, 6)
for name, source in (('virtual.h5', 'src.h5'), ('dangling.h5', 'gone.h5')):
    layout = h5py.VirtualLayout(shape=(4, 5, 6), dtype='u1')
    layout[:] = h5py.VirtualSource(source, 'data', shape=(4, 5, 6))
    with h5py.File(name, 'w') as f:
        f.create_virtual_dataset('data', layout, fillvalue=0)
)"));
  const Volume external = read_stack(dir / "external.h5");
  EXPECT_EQ(external.voxels[7], 7.0f);
  EXPECT_EQ(read_stack(dir / "virtual.h5").voxels[119], 119.0f);
  EXPECT_NE(error_of([&] { (void)read_stack(dir / "elsewhere.h5"); })
                .find("reads external raw storage '/etc/passwd', which is not in the stack's own folder"),
            std::string::npos)
      << error_of([&] { (void)read_stack(dir / "elsewhere.h5"); });
  EXPECT_NE(error_of([&] { (void)read_stack(dir / "dangling.h5"); })
                .find("reads the virtual source 'gone.h5', which is not a regular file"),
            std::string::npos)
      << error_of([&] { (void)read_stack(dir / "dangling.h5"); });
}

}  // namespace
}  // namespace hisnegs::io
