// SPDX-License-Identifier: Apache-2.0
// io/volume_source: the memory, TIFF and HDF5 sources of one stack read the same
// voxels for any box, also from several threads at once; the streaming statistics
// pass gives exactly the normalization normalize() computes on the whole stack.
#include "io/detail/tiff_handle.hpp"
#include "io/volume_source.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <barrier>
#include <cstdlib>
#include <numeric>
#include <random>
#include <thread>

#include "io/error.hpp"
#include "io/hdf5_stack.hpp"
#include "io/tiff_stack.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {
using hisnegs::testing::ScratchDir;

Volume stack(SampleType type, std::uint64_t seed) {
  Volume v;
  v.nx = 45, v.ny = 31, v.nz = 13;
  v.stored_as = type;
  v.source = "s";
  v.voxels.resize(v.size());
  std::mt19937_64 rng(seed);
  // Mostly background, some bright: percentiles then differ from min and max.
  std::uniform_real_distribution<double> u(0.0, 1.0);
  const double top = type == SampleType::kUint8 ? 255.0 : 4000.0;
  for (float& x : v.voxels) x = static_cast<float>(std::floor(u(rng) < 0.9 ? u(rng) * 5 : u(rng) * top));
  return v;
}

// stack(), or for float32 a 16-bit one scaled and shifted off the integers.
Volume stack_of_any_type(SampleType type, std::uint64_t seed) {
  Volume v = stack(type == SampleType::kFloat32 ? SampleType::kUint16 : type, seed);
  if (type == SampleType::kFloat32) {
    v.stored_as = SampleType::kFloat32;
    for (float& x : v.voxels) x = x * 0.731f + 0.25f;
  }
  return v;
}

// A box of random position and extent inside `v` (at least one voxel).
VoxelBox random_box(const Volume& v, std::mt19937& rng) {
  VoxelBox b;
  const std::array<int, 3> n{v.nx, v.ny, v.nz};
  for (int a = 0; a < 3; ++a) {
    b.lo[a] = std::uniform_int_distribution<int>(0, n[a] - 1)(rng);
    b.hi[a] = std::uniform_int_distribution<int>(b.lo[a] + 1, n[a])(rng);
  }
  return b;
}

std::vector<float> read_box(const VolumeSource& s, const VoxelBox& b) {
  std::vector<float> out(b.voxels());
  s.read(b, out.data());
  return out;
}

TEST(VolumeSource, MemoryTiffAndHdf5ReadTheSameBoxes) {
  ScratchDir dir;
  const Volume v = stack(SampleType::kUint16, 3);
  write_tiff_stack(dir / "s.tif", v.voxels, v.nx, v.ny, v.nz, {.type = SampleType::kUint16});
  write_hdf5_stack(dir / "s.h5", v, {.type = SampleType::kUint16, .chunk_zyx = {4, 8, 8}});
  const auto mem = memory_source(v);
  const auto tif = open_volume_source(dir / "s.tif");
  const auto h5 = open_volume_source(dir / "s.h5");
  for (const VolumeSource* s : {tif.get(), h5.get()}) {
    EXPECT_EQ(s->nx, v.nx);
    EXPECT_EQ(s->ny, v.ny);
    EXPECT_EQ(s->nz, v.nz);
    EXPECT_EQ(s->stored_as, SampleType::kUint16);
  }
  EXPECT_NE(h5->format.find("HDF5, data 13x31x45"), std::string::npos) << h5->format;
  std::mt19937 rng(5);
  for (int k = 0; k < 25; ++k) {
    const VoxelBox b = random_box(v, rng);
    const std::vector<float> expected = read_box(*mem, b);
    ASSERT_EQ(read_box(*tif, b), expected) << k;
    ASSERT_EQ(read_box(*h5, b), expected) << k;
  }
  EXPECT_EQ(read_box(*h5, h5->whole()), v.voxels);
  EXPECT_THROW(read_box(*tif, VoxelBox{{0, 0, 0}, {v.nx + 1, 1, 1}}), std::invalid_argument);
}

TEST(VolumeSource, ConcurrentReadsAgree) {
  ScratchDir dir;
  const Volume v = stack(SampleType::kUint8, 4);
  write_tiff_stack(dir / "s.tif", v.voxels, v.nx, v.ny, v.nz, {.type = SampleType::kUint8});
  write_hdf5_stack(dir / "s.h5", v, {.type = SampleType::kUint8, .chunk_zyx = {2, 16, 16}});
  for (const char* name : {"s.tif", "s.h5"}) {
    const auto s = open_volume_source(dir / name);
    // A read leaves its thread's diagnostics sink as it found it: a pooled handle
    // is put aside (TiffHandle::deactivate) before another thread may take it.
    std::thread first([&] {
      (void)read_box(*s, {{0, 0, 0}, {v.nx, v.ny, 1}});
      EXPECT_EQ(detail::exchange_active_messages(nullptr), nullptr) << name << ": a read left its handle as the sink";
    });
    first.join();
    std::vector<std::vector<float>> slabs(static_cast<std::size_t>(v.nz));
    std::vector<std::thread> threads;
    for (int t = 0; t < 4; ++t) {
      threads.emplace_back([&, t] {
        for (int z = t; z < v.nz; z += 4) slabs[static_cast<std::size_t>(z)] = read_box(*s, {{0, 0, z}, {v.nx, v.ny, z + 1}});
      });
    }
    for (auto& th : threads) th.join();
    std::vector<float> all;
    for (const auto& slab : slabs) all.insert(all.end(), slab.begin(), slab.end());
    EXPECT_EQ(all, v.voxels) << name;
  }
}

TEST(VolumeSource, StreamingStatisticsNormalizeAsTheWholeStackDoes) {
  for (const SampleType type : {SampleType::kUint8, SampleType::kUint16}) {
    const Volume v = stack(type, 9);
    const auto s = memory_source(v);
    // Slabs of one page, of four, and the whole stack: the same statistics.
    for (const std::size_t slab : {std::size_t{1}, std::size_t{4 * 45 * 31 * 4}, std::size_t{1} << 30}) {
      const SourceStatistics st = scan_statistics(*s, slab);
      EXPECT_EQ(st.voxels, static_cast<std::int64_t>(v.size()));
      for (const NormalizationMethod m : {NormalizationMethod::kMinMax, NormalizationMethod::kPercentile}) {
        NormalizationOptions o;
        o.method = m;
        o.percentile_lo = 2.5;
        o.percentile_hi = 97.3;
        Volume whole = v;
        normalize(whole, o);
        const Normalization n = normalization_from(st, o, "s");
        EXPECT_EQ(n.raw_lo, whole.normalization.raw_lo) << to_string(type) << " " << to_string(m);
        EXPECT_EQ(n.raw_hi, whole.normalization.raw_hi) << to_string(type) << " " << to_string(m);
        EXPECT_EQ(n.clipped_voxels, whole.normalization.clipped_voxels) << to_string(type) << " " << to_string(m);
      }
    }
  }
  Volume flat = stack(SampleType::kUint8, 1);
  std::fill(flat.voxels.begin(), flat.voxels.end(), 7.0f);
  EXPECT_THROW((void)normalization_from(scan_statistics(*memory_source(flat)), {}, "flat.tif"), InputError);
}

// float32 stacks: percentiles from two streaming passes (2^20 bins over [min, max])
// within one bin width of normalize()'s exact ones; slabs smaller than a page (bands
// of rows) see the same statistics.
TEST(VolumeSource, Float32PercentilesAreWithinOneBinOfTheExactOnes) {
  Volume v = stack(SampleType::kUint16, 3);
  v.stored_as = SampleType::kFloat32;
  std::mt19937 rng(2);
  std::normal_distribution<float> jitter(0.0f, 3.0f);
  for (float& x : v.voxels) x = x * 1.37f + jitter(rng);
  const auto s = memory_source(v);
  for (const std::size_t slab : {std::size_t{100}, std::size_t{1} << 30}) {
    const SourceStatistics st = scan_statistics(*s, slab);
    const double bin = (st.max - st.min) / static_cast<double>(SourceStatistics::kFloatBins);
    for (const double lo : {0.1, 2.5, 50.0}) {
      NormalizationOptions o;
      o.method = NormalizationMethod::kPercentile;
      o.percentile_lo = lo;
      o.percentile_hi = 99.9;
      Volume whole = v;
      normalize(whole, o);
      const Normalization n = normalization_from(st, o, "f");
      EXPECT_NEAR(n.raw_lo, whole.normalization.raw_lo, bin) << lo << " slab " << slab;
      EXPECT_NEAR(n.raw_hi, whole.normalization.raw_hi, bin) << "slab " << slab;
    }
  }
}

// Cells' coarse histograms, taken in the statistics pass, give each cell's
// foreground: exactly for 8-bit stacks; for 16-bit ones within the cell's voxels in
// the coarse bin (16 per octave) the threshold splits, also for a 16-bit stack
// whose values all lie below 256 (coarse bins of 256 values would see one bin). A pass of slabs of bands of
// rows takes the same histograms as one of pages.
TEST(VolumeSource, CellHistogramsGiveEachCellsForeground) {
  const CellGrid cells{{16, 11, 5}, {3, 3, 3}};  // the last cell of each axis shorter
  for (const auto& [type, narrow] : std::vector<std::pair<SampleType, bool>>{
           {SampleType::kUint8, false}, {SampleType::kUint16, false}, {SampleType::kUint16, true}}) {
    SCOPED_TRACE(::testing::Message() << to_string(type) << (narrow ? ", values below 256" : ""));
    Volume v = stack(type, 13);
    if (narrow) {
      for (float& x : v.voxels) x = std::floor(x / 16.0f);  // a 16-bit stack using 0..249
    }
    const auto s = memory_source(v);
    const SourceStatistics st = scan_statistics(*s, 4 * 45 * 31 * 3, {}, &cells);
    EXPECT_EQ(scan_statistics(*s, 4 * 45 * 7, {}, &cells).cell_histograms, st.cell_histograms);
    ASSERT_EQ(st.cell_histograms.size(), cells.cells() * SourceStatistics::kCellBins);
    Volume whole = v;
    normalize(whole, {});
    // which coarse bins the threshold splits (some values above it, some not)
    std::vector<float> values(st.histogram.size());
    std::iota(values.begin(), values.end(), 0.0f);
    (void)apply_normalization(values, whole.normalization);
    for (const double threshold : {0.05, 0.2, 0.6}) {
      std::vector<int> above(SourceStatistics::kCellBins, 0), below(SourceStatistics::kCellBins, 0);
      for (std::size_t x = 0; x < values.size(); ++x) (values[x] > threshold ? above : below)[st.cell_bin(x)] = 1;
      std::vector<std::int64_t> exact(cells.cells(), 0);
      for (int z = 0; z < v.nz; ++z) {
        for (int y = 0; y < v.ny; ++y) {
          for (int x = 0; x < v.nx; ++x) {
            const auto c = static_cast<std::size_t>((z / 5 * 3 + y / 11) * 3 + x / 16);
            exact[c] += whole.voxels[v.index(x, y, z)] > threshold ? 1 : 0;
          }
        }
      }
      const std::vector<std::int64_t> got = cell_counts_above(st, whole.normalization, threshold);
      ASSERT_EQ(got.size(), exact.size());
      std::int64_t split_total = 0;  // voxels whose bin the threshold splits: few
      for (std::size_t c = 0; c < got.size(); ++c) {
        std::int64_t split = 0;  // the cell's voxels in split bins
        for (std::size_t b = 0; b < SourceStatistics::kCellBins; ++b) {
          split += above[b] != 0 && below[b] != 0 ? st.cell_histograms[c * SourceStatistics::kCellBins + b] : 0;
        }
        split_total += split;
        if (type == SampleType::kUint8) {
          EXPECT_EQ(split, 0);
        }
        EXPECT_LE(std::abs(got[c] - exact[c]), split) << "cell " << c << ", threshold " << threshold;
      }
      EXPECT_GT(std::accumulate(exact.begin(), exact.end(), std::int64_t{0}), 0);
      EXPECT_LT(split_total, static_cast<std::int64_t>(v.size() / 20)) << "threshold " << threshold;
    }
  }
  EXPECT_THROW((void)cell_counts_above(SourceStatistics{}, Normalization{}, 0.2), std::logic_error);
}

// The foreground count of a stack read by slabs equals the count over the whole
// normalized stack: from the histogram (8/16-bit) and from a pass of slabs (float32,
// whose histogram holds bins, not values).
TEST(VolumeSource, CountAboveAThresholdMatchesTheNormalizedStack) {
  for (const SampleType type : {SampleType::kUint8, SampleType::kUint16, SampleType::kFloat32}) {
    const Volume v = stack_of_any_type(type, 5);
    const auto s = memory_source(v);
    const SourceStatistics st = scan_statistics(*s, 4 * 45 * 31 * 3);
    Volume whole = v;
    normalize(whole, {});
    for (const double threshold : {0.0, 0.05, 0.2, 0.9}) {
      const auto expected = std::count_if(whole.voxels.begin(), whole.voxels.end(), [&](float x) { return x > threshold; });
      EXPECT_EQ(count_above(*s, st, whole.normalization, threshold, 4 * 45 * 31 * 2), expected)
          << to_string(type) << " threshold " << threshold;
    }
  }
}

// Parts of one scan meeting through their sum and max, as the ranks of a job do
// (apps::scan_share): here threads, each part's values put in its slot and combined
// in part order once all are in.
class ThreadedShares {
 public:
  explicit ThreadedShares(int parts) : slots_(static_cast<std::size_t>(parts)), sync_(parts) {}

  ScanShare share(int part) {
    ScanShare s;
    s.part = part;
    s.parts = static_cast<int>(slots_.size());
    s.sum = [this, part](std::span<double> v) { combine(part, v, [](double a, double b) { return a + b; }); };
    s.max = [this, part](std::span<double> v) { combine(part, v, [](double a, double b) { return std::max(a, b); }); };
    return s;
  }

 private:
  template <class Op>
  void combine(int part, std::span<double> values, Op op) {
    slots_[static_cast<std::size_t>(part)].assign(values.begin(), values.end());
    sync_.arrive_and_wait();  // every part's values are in
    for (std::size_t i = 0; i < values.size(); ++i) {
      double whole = slots_[0][i];
      for (std::size_t p = 1; p < slots_.size(); ++p) whole = op(whole, slots_[p][i]);
      values[i] = whole;
    }
    sync_.arrive_and_wait();  // every part has read them
  }

  std::vector<std::vector<double>> slots_;
  std::barrier<> sync_;
};

// A scan shared by parts (pages split between them; more parts than pages leaves
// some with none) gives one process's statistics exactly, for 8/16-bit and float32
// stacks (and so its normalization and foreground count).
TEST(VolumeSource, AScanSharedByPartsEqualsOneProcesssScan) {
  for (const SampleType type : {SampleType::kUint8, SampleType::kUint16, SampleType::kFloat32}) {
    const Volume v = stack_of_any_type(type, 11);
    const auto s = memory_source(v);
    const std::size_t slab = 4 * 45 * 31 * 2;
    const CellGrid cells{{20, 20, 4}, {3, 2, 4}};
    const SourceStatistics one = scan_statistics(*s, slab, {}, &cells);
    const Normalization map = normalization_from(one, {}, "s");
    const std::int64_t above = count_above(*s, one, map, 0.2, slab);
    for (const int parts : {2, 3, 17}) {
      ThreadedShares shares(parts);
      std::vector<SourceStatistics> got(static_cast<std::size_t>(parts));
      std::vector<std::thread> threads;
      for (int p = 0; p < parts; ++p) {
        threads.emplace_back([&, p] {
          const ScanShare share = shares.share(p);
          got[static_cast<std::size_t>(p)] = scan_statistics(*s, slab, share, &cells);
        });
      }
      for (auto& t : threads) t.join();
      for (int p = 0; p < parts; ++p) {
        const SourceStatistics& st = got[static_cast<std::size_t>(p)];
        SCOPED_TRACE(::testing::Message() << to_string(type) << ", part " << p << " of " << parts);
        EXPECT_EQ(st.min, one.min);
        EXPECT_EQ(st.max, one.max);
        EXPECT_EQ(st.voxels, one.voxels);
        EXPECT_EQ(st.bin_width, one.bin_width);
        EXPECT_EQ(st.histogram, one.histogram);
        EXPECT_EQ(st.cell_histograms, one.cell_histograms);  // none for float32
        EXPECT_EQ(count_above(*s, st, normalization_from(st, {}, "s"), 0.2, slab), above);
      }
    }
  }
}

// Tiled and many-strip TIFFs (written by tifffile): a region read decodes only the
// tiles or strips it meets, and reads the same voxels as the whole stack.
TEST(VolumeSource, TiledAndStripedTiffRegions) {
  if (std::system("/usr/bin/python3 -c 'import tifffile, numpy' 2>/dev/null") != 0) {
    if (std::getenv("CI")) FAIL() << "python3-tifffile is missing; scripts/install-deps.sh installs it";
    GTEST_SKIP() << "python3 with tifffile is not installed";
  }
  ScratchDir dir;
  const Volume v = stack(SampleType::kUint16, 6);
  write_tiff_stack(dir / "s.tif", v.voxels, v.nx, v.ny, v.nz, {.type = SampleType::kUint16});
  const auto r = hisnegs::testing::run_shell(
      "cd " + hisnegs::testing::shell_quoted(dir.path()) +
      " && /usr/bin/python3 -c 'import tifffile\n"
      "a = tifffile.imread(\"s.tif\")\n"
      "tifffile.imwrite(\"tiled.tif\", a, tile=(16, 16))\n"
      "tifffile.imwrite(\"strips.tif\", a, rowsperstrip=3)'");
  ASSERT_EQ(r.status, 0) << r.out;
  const auto mem = memory_source(v);
  for (const char* name : {"s.tif", "tiled.tif", "strips.tif"}) {
    const auto s = open_volume_source(dir / name);  // reads through the file's page index
    const auto index = index_tiff_pages(dir / name);
    std::mt19937 rng(8);
    for (int k = 0; k < 20; ++k) {
      const VoxelBox b = random_box(v, rng);
      const std::vector<float> expected = read_box(*mem, b);
      ASSERT_EQ(read_box(*s, b), expected) << name << " box " << k;
      // The chain walked from page 0 and the index's offsets read the same voxels.
      std::vector<float> walked(b.voxels()), indexed(b.voxels());
      read_tiff_region(dir / name, {}, b.lo, b.hi, walked.data());
      read_tiff_region(dir / name, {}, b.lo, b.hi, indexed.data(), index.get());
      ASSERT_EQ(walked, expected) << name << " box " << k;
      ASSERT_EQ(indexed, expected) << name << " box " << k;
    }
  }
}

}  // namespace
}  // namespace hisnegs::io
