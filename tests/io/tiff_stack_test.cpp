// SPDX-License-Identifier: Apache-2.0
// Tests of io/tiff_stack: round trips, layouts and codecs (fixtures written with libtiff directly),
// channel selection, spacing precedence and bad inputs. Metadata text parsing is tiff_metadata_test's.
#include "io/tiff_stack.hpp"

#include <gtest/gtest.h>
#include <tiffio.h>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "io/error.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::io {
namespace {
namespace fs = std::filesystem;
using hisnegs::testing::ScratchDir;

// ---------------------------------------------------------------------------
// Fixture writer: libtiff directly, so the reader is tested against files it did not write.

struct Fixture {
  int nx = 7, ny = 5, pages = 3;
  const char* mode = "w";  // "w8" for BigTIFF
  std::uint16_t bits = 8;
  std::uint16_t sample_format = SAMPLEFORMAT_UINT;
  std::uint16_t samples = 1;
  std::uint16_t planar = PLANARCONFIG_CONTIG;
  std::uint16_t photometric = PHOTOMETRIC_MINISBLACK;
  std::uint16_t compression = COMPRESSION_NONE;
  std::uint32_t tile = 0;                    // square tile size; 0 writes strips
  std::uint32_t rows_per_strip = 0;          // 0: one strip per page
  std::string description;                   // page 0's ImageDescription ("" = none)
  float x_resolution = 0, y_resolution = 0;  // written when > 0
  std::uint16_t resolution_unit = RESUNIT_NONE;
  // Value of sample `s` of pixel (x, y) on page `page`.
  std::function<double(int page, int s, int x, int y)> value = [](int page, int s, int x, int y) {
    return (page * 31 + s * 7 + x * 3 + y * 5) % 251;
  };
};

void store(const Fixture& f, double v, unsigned char* dst) {
  auto put = [&](auto typed) { std::memcpy(dst, &typed, sizeof typed); };
  const bool is_float = f.sample_format == SAMPLEFORMAT_IEEEFP;
  const bool is_signed = f.sample_format == SAMPLEFORMAT_INT;
  switch (f.bits) {
    case 8:
      is_signed ? put(static_cast<std::int8_t>(v)) : put(static_cast<std::uint8_t>(v));
      break;
    case 16:
      is_signed ? put(static_cast<std::int16_t>(v)) : put(static_cast<std::uint16_t>(v));
      break;
    case 32:
      if (is_float)
        put(static_cast<float>(v));
      else if (is_signed)
        put(static_cast<std::int32_t>(v));
      else
        put(static_cast<std::uint32_t>(v));
      break;
    case 64:
      put(v);
      break;
    default:
      FAIL() << "fixture: unsupported bits";
  }
}

void write_fixture(const fs::path& path, const Fixture& f) {
  TIFF* tif = TIFFOpen(path.c_str(), f.mode);
  ASSERT_NE(tif, nullptr);
  const std::size_t bytes = f.bits / 8;
  const bool separate = f.planar == PLANARCONFIG_SEPARATE;
  const std::size_t per_pixel = separate ? 1 : f.samples;
  for (int page = 0; page < f.pages; ++page) {
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, static_cast<std::uint32_t>(f.nx));
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, static_cast<std::uint32_t>(f.ny));
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, f.bits);
    TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT, f.sample_format);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, f.samples);
    TIFFSetField(tif, TIFFTAG_PLANARCONFIG, f.planar);
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, f.photometric);
    TIFFSetField(tif, TIFFTAG_COMPRESSION, f.compression);
    if (page == 0 && !f.description.empty()) TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, f.description.c_str());
    if (f.x_resolution > 0) TIFFSetField(tif, TIFFTAG_XRESOLUTION, f.x_resolution);
    if (f.y_resolution > 0) TIFFSetField(tif, TIFFTAG_YRESOLUTION, f.y_resolution);
    if (f.x_resolution > 0 || f.y_resolution > 0) TIFFSetField(tif, TIFFTAG_RESOLUTIONUNIT, f.resolution_unit);
    const int planes = separate ? f.samples : 1;
    if (f.tile > 0) {
      TIFFSetField(tif, TIFFTAG_TILEWIDTH, f.tile);
      TIFFSetField(tif, TIFFTAG_TILELENGTH, f.tile);
      std::vector<unsigned char> buf(f.tile * f.tile * per_pixel * bytes);
      for (int plane = 0; plane < planes; ++plane) {
        for (std::uint32_t ty = 0; ty < static_cast<std::uint32_t>(f.ny); ty += f.tile) {
          for (std::uint32_t tx = 0; tx < static_cast<std::uint32_t>(f.nx); tx += f.tile) {
            std::fill(buf.begin(), buf.end(), 0);
            for (std::uint32_t r = 0; r < f.tile && ty + r < static_cast<std::uint32_t>(f.ny); ++r) {
              for (std::uint32_t c = 0; c < f.tile && tx + c < static_cast<std::uint32_t>(f.nx); ++c) {
                for (std::size_t k = 0; k < per_pixel; ++k) {
                  const int s = separate ? plane : static_cast<int>(k);
                  store(f, f.value(page, s, static_cast<int>(tx + c), static_cast<int>(ty + r)),
                        &buf[((r * f.tile + c) * per_pixel + k) * bytes]);
                }
              }
            }
            const std::uint32_t tile = TIFFComputeTile(tif, tx, ty, 0, static_cast<std::uint16_t>(plane));
            ASSERT_GT(TIFFWriteEncodedTile(tif, tile, buf.data(), static_cast<tmsize_t>(buf.size())), 0);
          }
        }
      }
    } else {
      const std::uint32_t rps = f.rows_per_strip ? f.rows_per_strip : static_cast<std::uint32_t>(f.ny);
      TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, rps);
      std::vector<unsigned char> buf(rps * f.nx * per_pixel * bytes);
      for (int plane = 0; plane < planes; ++plane) {
        for (std::uint32_t row = 0; row < static_cast<std::uint32_t>(f.ny); row += rps) {
          const std::uint32_t rows = std::min<std::uint32_t>(rps, static_cast<std::uint32_t>(f.ny) - row);
          for (std::uint32_t r = 0; r < rows; ++r) {
            for (int x = 0; x < f.nx; ++x) {
              for (std::size_t k = 0; k < per_pixel; ++k) {
                const int s = separate ? plane : static_cast<int>(k);
                store(f, f.value(page, s, x, static_cast<int>(row + r)),
                      &buf[((r * f.nx + x) * per_pixel + k) * bytes]);
              }
            }
          }
          const std::uint32_t strip = TIFFComputeStrip(tif, row, static_cast<std::uint16_t>(plane));
          ASSERT_GT(
              TIFFWriteEncodedStrip(tif, strip, buf.data(), static_cast<tmsize_t>(rows * f.nx * per_pixel * bytes)), 0);
        }
      }
    }
    ASSERT_TRUE(TIFFWriteDirectory(tif));
  }
  TIFFClose(tif);
}

// Expects read values to equal f.value for sample `s` on the pages in `page_of_z`.
void expect_values(const Volume& v, const Fixture& f, int s, const std::vector<int>& page_of_z) {
  ASSERT_EQ(v.nx, f.nx);
  ASSERT_EQ(v.ny, f.ny);
  ASSERT_EQ(v.nz, static_cast<int>(page_of_z.size()));
  int mismatches = 0;
  for (int z = 0; z < v.nz; ++z) {
    for (int y = 0; y < v.ny; ++y) {
      for (int x = 0; x < v.nx; ++x) {
        const auto expected = static_cast<float>(f.value(page_of_z[static_cast<std::size_t>(z)], s, x, y));
        if (v.at(x, y, z) != expected && ++mismatches <= 5) {
          ADD_FAILURE() << "voxel (" << x << ", " << y << ", " << z << "): " << v.at(x, y, z) << " != " << expected;
        }
      }
    }
  }
  EXPECT_EQ(mismatches, 0);
}

std::vector<int> iota_pages(int n, int first = 0, int step = 1) {
  std::vector<int> pages;
  for (int z = 0; z < n; ++z) pages.push_back(first + z * step);
  return pages;
}

// Reads `path` expecting InputError; checks that the message is one line naming
// the path, contains `expected`, and that libtiff printed nothing.
void expect_input_error(const fs::path& path, const std::string& expected, const TiffReadOptions& options = {}) {
  ::testing::internal::CaptureStderr();
  try {
    (void)read_tiff_stack(path, options);
    (void)::testing::internal::GetCapturedStderr();
    ADD_FAILURE() << "no InputError for " << path;
  } catch (const InputError& e) {
    const std::string stderr_text = ::testing::internal::GetCapturedStderr();
    const std::string what = e.what();
    EXPECT_NE(what.find(path.string()), std::string::npos) << what;
    EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    EXPECT_NE(what.find(expected), std::string::npos) << what;
    EXPECT_EQ(stderr_text, "") << "libtiff printed to stderr";
  }
}

std::vector<float> random_values(std::size_t n, SampleType type, unsigned seed) {
  std::mt19937 rng(seed);
  std::vector<float> v(n);
  if (type == SampleType::kFloat32) {
    std::uniform_real_distribution<float> d(-1e6f, 1e6f);
    for (float& x : v) x = d(rng);
    v[0] = -0.0f;
    v[1] = std::numeric_limits<float>::denorm_min();
    v[2] = std::numeric_limits<float>::max();
  } else {
    const int hi = type == SampleType::kUint8 ? 255 : 65535;
    std::uniform_int_distribution<int> d(0, hi);
    for (float& x : v) x = static_cast<float>(d(rng));
    v[0] = 0;
    v[1] = static_cast<float>(hi);
  }
  return v;
}

void expect_bit_identical(const std::vector<float>& a, const std::vector<float>& b) {
  ASSERT_EQ(a.size(), b.size());
  EXPECT_EQ(std::memcmp(a.data(), b.data(), a.size() * sizeof(float)), 0);
}

std::string image_description(const fs::path& path) {
  TIFF* tif = TIFFOpen(path.c_str(), "r");
  if (!tif) return "";
  const char* text = nullptr;
  std::string out;
  if (TIFFGetField(tif, TIFFTAG_IMAGEDESCRIPTION, &text) && text) out = text;
  TIFFClose(tif);
  return out;
}

// ---------------------------------------------------------------------------
// Round trips.

void round_trip(SampleType type, bool deflate, unsigned seed) {
  ScratchDir dir;
  const int nx = 37, ny = 23, nz = 5;
  const std::vector<float> values = random_values(static_cast<std::size_t>(nx) * ny * nz, type, seed);
  TiffWriteOptions options;
  options.type = type;
  options.deflate = deflate;
  options.spacing_um = std::array<double, 3>{0.3296, 0.41, 0.9988};
  const fs::path path = dir / "stack.tif";
  write_tiff_stack(path, values, nx, ny, nz, options);
  const Volume v = read_tiff_stack(path);
  EXPECT_EQ(v.nx, nx);
  EXPECT_EQ(v.ny, ny);
  EXPECT_EQ(v.nz, nz);
  EXPECT_EQ(v.stored_as, type);
  EXPECT_EQ(v.normalization.method, NormalizationMethod::kNone);
  expect_bit_identical(v.voxels, values);
  // X/Y go through TIFF's float rationals (~7 digits); z is written exactly.
  EXPECT_NEAR(v.spacing.um[0], 0.3296, 0.3296 * 1e-6);
  EXPECT_NEAR(v.spacing.um[1], 0.41, 0.41 * 1e-6);
  EXPECT_DOUBLE_EQ(v.spacing.um[2], 0.9988);
  EXPECT_EQ(v.spacing.source[0], SpacingSource::kImageJResolution);
  EXPECT_EQ(v.spacing.source[1], SpacingSource::kImageJResolution);
  EXPECT_EQ(v.spacing.source[2], SpacingSource::kImageJSpacing);
  const TiffStackInfo info = inspect_tiff_stack(path);
  EXPECT_EQ(info.compression, deflate ? "AdobeDeflate" : "None");
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"stack.tif"});  // no temp file left
}

TEST(TiffStackRoundTrip, Uint8IsBitIdentical) { round_trip(SampleType::kUint8, false, 1); }
TEST(TiffStackRoundTrip, Uint16IsBitIdentical) { round_trip(SampleType::kUint16, false, 2); }
TEST(TiffStackRoundTrip, Float32IsBitIdentical) { round_trip(SampleType::kFloat32, false, 3); }
TEST(TiffStackRoundTrip, DeflateUint8IsBitIdentical) { round_trip(SampleType::kUint8, true, 4); }
TEST(TiffStackRoundTrip, DeflateUint16IsBitIdentical) { round_trip(SampleType::kUint16, true, 5); }
TEST(TiffStackRoundTrip, DeflateFloat32IsBitIdentical) { round_trip(SampleType::kFloat32, true, 6); }

TEST(TiffStackRoundTrip, NoSpacingReadsBackAsDefault) {
  ScratchDir dir;
  const std::vector<float> values = random_values(4 * 3 * 2, SampleType::kUint8, 7);
  write_tiff_stack(dir / "a.tif", values, 4, 3, 2, {.type = SampleType::kUint8});
  const Volume v = read_tiff_stack(dir / "a.tif");
  for (int a = 0; a < 3; ++a) {
    EXPECT_EQ(v.spacing.um[static_cast<std::size_t>(a)], 1.0);
    EXPECT_EQ(v.spacing.source[static_cast<std::size_t>(a)], SpacingSource::kDefault);
  }
}

TEST(TiffStackRoundTrip, VolumeOverloadWritesItsSpacing) {
  ScratchDir dir;
  Volume v;
  v.nx = 3, v.ny = 2, v.nz = 2;
  v.voxels = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11};
  v.spacing.um = {0.5, 0.25, 2.0};
  v.spacing.source = {SpacingSource::kUser, SpacingSource::kUser, SpacingSource::kUser};
  write_tiff_stack(dir / "v.tif", v, TiffWriteOptions{.type = SampleType::kUint16});
  const Volume back = read_tiff_stack(dir / "v.tif");
  EXPECT_EQ(back.voxels, v.voxels);
  EXPECT_EQ(back.stored_as, SampleType::kUint16);
  EXPECT_NEAR(back.spacing.um[0], 0.5, 1e-7);
  EXPECT_NEAR(back.spacing.um[1], 0.25, 1e-7);
  EXPECT_DOUBLE_EQ(back.spacing.um[2], 2.0);
}

TEST(TiffStackWrite, WritesAnImageJDescription) {
  ScratchDir dir;
  const std::vector<float> values = {0, 1, 2, 3, 4, 5, 6, 7};
  write_tiff_stack(dir / "d.tif", values, 2, 2, 2,
                   {.type = SampleType::kUint8, .spacing_um = std::array<double, 3>{1, 1, 2.5}});
  EXPECT_EQ(image_description(dir / "d.tif"), "ImageJ=1.11a\nimages=2\nslices=2\nunit=um\nspacing=2.5\nmin=0\nmax=7\n");
}

// Each page's data offsets and byte counts, read with libtiff.
std::vector<std::pair<std::uint64_t, std::uint64_t>> page_strips(const fs::path& path) {
  std::vector<std::pair<std::uint64_t, std::uint64_t>> out;
  TIFF* tif = TIFFOpen(path.c_str(), "r");
  if (!tif) return out;
  do {
    for (std::uint32_t s = 0; s < TIFFNumberOfStrips(tif); ++s) {
      out.emplace_back(TIFFGetStrileOffset(tif, s), TIFFGetStrileByteCount(tif, s));
    }
  } while (TIFFReadDirectory(tif));
  TIFFClose(tif);
  return out;
}

// Issue 32, item 13: an uncompressed stack keeps the promise of its ImageJ
// `images=`: the pages' data lies back to back from page 0's, for every page count
// (a 2-page float stack, whose page 1 followed page 0's IFD, was read by tifffile
// 2023.2.3 as values up to 1.9e28). A compressed one makes no such promise.
TEST(TiffStackWrite, UncompressedPagesAreContiguousAsImagesPromises) {
  ScratchDir dir;
  for (const int nz : {1, 2, 3, 7}) {
    for (const SampleType type : {SampleType::kFloat32, SampleType::kUint16, SampleType::kUint8}) {
      SCOPED_TRACE(std::to_string(nz) + " pages of " + std::string(to_string(type)));
      const int nx = 13, ny = 9;
      const std::vector<float> values = random_values(static_cast<std::size_t>(nx) * ny * nz, type, 40u + nz);
      const fs::path path = dir / "c.tif";
      write_tiff_stack(path, values, nx, ny, nz, {.type = type});
      const auto strips = page_strips(path);
      ASSERT_EQ(strips.size(), static_cast<std::size_t>(nz));  // one strip per page
      const std::uint64_t page_bytes = static_cast<std::uint64_t>(nx) * ny * (type == SampleType::kFloat32 ? 4 : type == SampleType::kUint16 ? 2 : 1);
      for (int z = 0; z < nz; ++z) {
        EXPECT_EQ(strips[z].first, strips[0].first + z * page_bytes) << "page " << z;
        EXPECT_EQ(strips[z].second, page_bytes) << "page " << z;
      }
      EXPECT_EQ(strips[0].first + nz * page_bytes, fs::file_size(path));  // the data ends the file
      EXPECT_NE(image_description(path).find("\nimages=" + std::to_string(nz) + "\n"), std::string::npos);
      if (nz > 1) expect_bit_identical(read_tiff_stack(path).voxels, values);  // one page is no stack
    }
  }
  const std::vector<float> values = random_values(8 * 4 * 3, SampleType::kFloat32, 50);
  write_tiff_stack(dir / "z.tif", values, 8, 4, 3, {.type = SampleType::kFloat32, .deflate = true});
  EXPECT_EQ(image_description(dir / "z.tif").find("images="), std::string::npos);
  expect_bit_identical(read_tiff_stack(dir / "z.tif").voxels, values);
}

// The same files read back by tifffile (Debian's python3-tifffile, what many users
// open hisnegs' stacks with): every page count, every sample type, both layouts.
TEST(TiffStackWrite, TifffileReadsEveryPageCount) {
  // Debian's interpreter, where python3-tifffile installs (not a python3 earlier on PATH).
  if (std::system("/usr/bin/python3 -c 'import tifffile, numpy' 2>/dev/null") != 0) {
    if (std::getenv("CI")) FAIL() << "python3-tifffile is missing; scripts/install-deps.sh installs it";
    GTEST_SKIP() << "python3 with tifffile is not installed";
  }
  ScratchDir dir;
  int files = 0;
  for (const int nz : {1, 2, 3, 5}) {
    for (const SampleType type : {SampleType::kFloat32, SampleType::kUint16}) {
      for (const bool deflate : {false, true}) {
        const int nx = 11, ny = 7;
        const std::vector<float> values = random_values(static_cast<std::size_t>(nx) * ny * nz, type, 60u + nz);
        const std::string name = "t" + std::to_string(files++);
        write_tiff_stack(dir / (name + ".tif"), values, nx, ny, nz, {.type = type, .deflate = deflate});
        std::ofstream(dir / (name + ".f32"), std::ios::binary)
            .write(reinterpret_cast<const char*>(values.data()), static_cast<std::streamsize>(values.size() * 4));
      }
    }
  }
  // For each file: the largest difference from the values written, and the shape.
  const testing::ShellResult r = testing::run_shell(
      "cd " + testing::shell_quoted(dir.path()) +
      " && /usr/bin/python3 -c 'import glob, numpy, tifffile\n"
      "for t in sorted(glob.glob(\"t*.tif\")):\n"
      "    a = tifffile.imread(t).astype(numpy.float64)\n"
      "    b = numpy.fromfile(t[:-4] + \".f32\", dtype=\"<f4\").astype(numpy.float64)\n"
      "    print(t, a.size == b.size and float(abs(a.ravel() - b).max()) == 0.0, a.shape)'");
  ASSERT_EQ(r.status, 0) << r.out;
  EXPECT_EQ(testing::count_lines(r.out), files) << r.out;
  EXPECT_EQ(r.out.find("False"), std::string::npos) << r.out;
}

TEST(TiffStackWrite, Uint8RejectsOutOfRangeValue) {
  ScratchDir dir;
  std::vector<float> values(4 * 3 * 2, 1.0f);
  values[4 * 3 + 5] = 300.0f;  // x=1, y=1, z=1
  try {
    write_tiff_stack(dir / "bad.tif", values, 4, 3, 2, {.type = SampleType::kUint8});
    FAIL() << "no InputError";
  } catch (const InputError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find((dir / "bad.tif").string()), std::string::npos) << what;
    EXPECT_NE(what.find("x=1, y=1, z=1"), std::string::npos) << what;
    EXPECT_NE(what.find("uint8"), std::string::npos) << what;
  }
  EXPECT_TRUE(dir.entries().empty());
}

TEST(TiffStackWrite, Uint8RejectsFractionalValue) {
  ScratchDir dir;
  std::vector<float> values(4 * 3 * 2, 1.0f);
  values[2] = 1.5f;
  EXPECT_THROW(write_tiff_stack(dir / "bad.tif", values, 4, 3, 2, {.type = SampleType::kUint8}), InputError);
  EXPECT_TRUE(dir.entries().empty());
}

TEST(TiffStackWrite, Uint16RejectsNegativeValue) {
  ScratchDir dir;
  std::vector<float> values(8, 1.0f);
  values[7] = -1.0f;
  EXPECT_THROW(write_tiff_stack(dir / "bad.tif", values, 2, 2, 2, {.type = SampleType::kUint16}), InputError);
  EXPECT_TRUE(dir.entries().empty());
}

TEST(TiffStackWrite, RejectsNaNAndLeavesNoFile) {
  ScratchDir dir;
  std::vector<float> values(8, 0.5f);
  values[3] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_THROW(write_tiff_stack(dir / "bad.tif", values, 2, 2, 2), InputError);
  EXPECT_TRUE(dir.entries().empty());
}

TEST(TiffStackWrite, FailedWriteLeavesNoTempFile) {
  ScratchDir dir;
  // The target is an existing folder: AtomicFile refuses before anything is written.
  fs::create_directory(dir / "out.tif");
  const std::vector<float> values(8, 0.5f);
  EXPECT_THROW(write_tiff_stack(dir / "out.tif", values, 2, 2, 2), InputError);
  EXPECT_EQ(dir.entries(), std::vector<std::string>{"out.tif"});
}

TEST(TiffStackWrite, RejectsInvalidSpacing) {
  ScratchDir dir;
  const std::vector<float> values(8, 0.5f);
  EXPECT_THROW(write_tiff_stack(dir / "a.tif", values, 2, 2, 2, {.spacing_um = std::array<double, 3>{1, 0, 1}}),
               InputError);
  EXPECT_THROW(write_tiff_stack(dir / "a.tif", values, 2, 2, 3), std::invalid_argument);
  EXPECT_TRUE(dir.entries().empty());
}

// ---------------------------------------------------------------------------
// Layouts and codecs.

TEST(TiffStackLayout, TiledPagesNotAMultipleOfTheTileSize) {
  ScratchDir dir;
  Fixture f;
  f.nx = 37, f.ny = 23, f.pages = 3, f.tile = 16, f.bits = 16;
  f.value = [](int page, int, int x, int y) { return page * 1000 + y * 40 + x; };
  write_fixture(dir / "tiled.tif", f);
  const Volume v = read_tiff_stack(dir / "tiled.tif");
  EXPECT_EQ(v.stored_as, SampleType::kUint16);
  expect_values(v, f, 0, iota_pages(3));
  EXPECT_TRUE(inspect_tiff_stack(dir / "tiled.tif").tiled);
}

TEST(TiffStackLayout, MultipleStripsPerPage) {
  ScratchDir dir;
  Fixture f;
  f.nx = 9, f.ny = 11, f.pages = 2, f.rows_per_strip = 4;
  write_fixture(dir / "strips.tif", f);
  expect_values(read_tiff_stack(dir / "strips.tif"), f, 0, iota_pages(2));
}

TEST(TiffStackLayout, PlanarSeparateRgbChannelOne) {
  ScratchDir dir;
  Fixture f;
  f.nx = 13, f.ny = 6, f.pages = 4, f.samples = 3, f.planar = PLANARCONFIG_SEPARATE;
  f.photometric = PHOTOMETRIC_RGB;
  f.value = [](int page, int s, int x, int y) { return s * 80 + page * 10 + (x + y) % 10; };
  write_fixture(dir / "rgb.tif", f);
  expect_values(read_tiff_stack(dir / "rgb.tif", {.channel = 1}), f, 1, iota_pages(4));
}

TEST(TiffStackLayout, PlanarSeparateTiledChannelTwo) {
  ScratchDir dir;
  Fixture f;
  f.nx = 21, f.ny = 18, f.pages = 3, f.samples = 3, f.planar = PLANARCONFIG_SEPARATE, f.tile = 16;
  f.photometric = PHOTOMETRIC_RGB, f.bits = 32, f.sample_format = SAMPLEFORMAT_IEEEFP;
  f.value = [](int page, int s, int x, int y) { return s * 100.5 + page * 10 - x * 0.125 + y; };
  write_fixture(dir / "rgb.tif", f);
  expect_values(read_tiff_stack(dir / "rgb.tif", {.channel = 2}), f, 2, iota_pages(3));
}

TEST(TiffStackLayout, ContiguousRgbChannelTwoTiled) {
  ScratchDir dir;
  Fixture f;
  f.nx = 20, f.ny = 17, f.pages = 2, f.samples = 3, f.tile = 16, f.photometric = PHOTOMETRIC_RGB;
  f.value = [](int page, int s, int x, int y) { return s * 80 + page * 10 + (x * y) % 10; };
  write_fixture(dir / "rgb.tif", f);
  expect_values(read_tiff_stack(dir / "rgb.tif", {.channel = 2}), f, 2, iota_pages(2));
  EXPECT_EQ(inspect_tiff_stack(dir / "rgb.tif").channels, 3);
}

TEST(TiffStackLayout, BigTiff) {
  ScratchDir dir;
  Fixture f;
  f.mode = "w8", f.nx = 10, f.ny = 8, f.pages = 3, f.bits = 32, f.sample_format = SAMPLEFORMAT_IEEEFP;
  f.value = [](int page, int, int x, int y) { return page - 0.25 * x + y * 1e-3; };
  write_fixture(dir / "big.tif", f);
  expect_values(read_tiff_stack(dir / "big.tif"), f, 0, iota_pages(3));
  EXPECT_TRUE(inspect_tiff_stack(dir / "big.tif").bigtiff);
}

TEST(TiffStackLayout, LzwCompressed) {
  ScratchDir dir;
  Fixture f;
  f.nx = 31, f.ny = 19, f.pages = 4, f.compression = COMPRESSION_LZW, f.bits = 16;
  f.value = [](int page, int, int x, int y) { return (page * 7919 + x * 104 + y * 13) % 65536; };
  write_fixture(dir / "lzw.tif", f);
  expect_values(read_tiff_stack(dir / "lzw.tif"), f, 0, iota_pages(4));
  EXPECT_EQ(inspect_tiff_stack(dir / "lzw.tif").compression, "LZW");
}

TEST(TiffStackLayout, ImageJHyperstackChannelPicksInterleavedPages) {
  ScratchDir dir;
  Fixture f;
  f.pages = 6;  // C=2 fastest, Z=3: page = z*2 + c
  f.description = "ImageJ=1.53t\nimages=6\nchannels=2\nslices=3\nhyperstack=true\nmode=composite\n";
  write_fixture(dir / "hyper.tif", f);
  expect_values(read_tiff_stack(dir / "hyper.tif", {.channel = 1}), f, 0, {1, 3, 5});
  expect_values(read_tiff_stack(dir / "hyper.tif", {.channel = 0}), f, 0, {0, 2, 4});
  const TiffStackInfo info = inspect_tiff_stack(dir / "hyper.tif");
  EXPECT_EQ(info.channels, 2);
  EXPECT_EQ(info.nz, 3);
  EXPECT_EQ(info.pages, 6);
}

TEST(TiffStackLayout, ImageJHyperstackWithoutChannelIsAnError) {
  ScratchDir dir;
  Fixture f;
  f.pages = 6;
  f.description = "ImageJ=1.53t\nimages=6\nchannels=2\nslices=3\nhyperstack=true\n";
  write_fixture(dir / "hyper.tif", f);
  expect_input_error(dir / "hyper.tif", "has 2 channels; choose one with --channel (0..1)");
  expect_input_error(dir / "hyper.tif", "channel 2 is out of range", {.channel = 2});
}

TEST(TiffStackLayout, OmeXmlDimensionOrderXYZCT) {
  ScratchDir dir;
  Fixture f;
  f.pages = 8;  // Z=4 fastest, then C=2: page = c*4 + z
  f.description =
      "<?xml version=\"1.0\"?><OME xmlns=\"http://www.openmicroscopy.org/Schemas/OME/2016-06\"><Image ID='Image:0'>"
      "<Pixels ID='Pixels:0' DimensionOrder='XYZCT' Type='uint8' SizeX='7' SizeY='5' SizeZ='4' SizeC='2' "
      "SizeT='1'><Channel ID='Channel:0:0'/></Pixels></Image></OME>";
  write_fixture(dir / "ome.tif", f);
  expect_values(read_tiff_stack(dir / "ome.tif", {.channel = 1}), f, 0, {4, 5, 6, 7});
}

TEST(TiffStackLayout, OmeXmlDimensionOrderXYCZT) {
  ScratchDir dir;
  Fixture f;
  f.pages = 6;  // C=3 fastest, then Z=2: page = z*3 + c
  f.description =
      "<OME><Image><Pixels SizeC=\"3\" SizeZ=\"2\" SizeT=\"1\" SizeY=\"5\" SizeX=\"7\" DimensionOrder=\"XYCZT\"/>"
      "</Image></OME>";
  write_fixture(dir / "ome.tif", f);
  expect_values(read_tiff_stack(dir / "ome.tif", {.channel = 2}), f, 0, {2, 5});
}

// ---------------------------------------------------------------------------
// Spacing precedence.

TEST(TiffStackSpacing, ImageJResolutionAndSpacing) {
  ScratchDir dir;
  Fixture f;
  f.description = "ImageJ=1.11a\nimages=3\nslices=3\nspacing=0.9988\nunit=um\n";
  f.x_resolution = 3.0336f, f.y_resolution = 3.0336f;
  write_fixture(dir / "ij.tif", f);
  const Volume v = read_tiff_stack(dir / "ij.tif");
  EXPECT_NEAR(v.spacing.um[0], 1.0 / 3.0336, 1e-7);
  EXPECT_NEAR(v.spacing.um[1], 1.0 / 3.0336, 1e-7);
  EXPECT_DOUBLE_EQ(v.spacing.um[2], 0.9988);
  EXPECT_EQ(v.spacing.source[0], SpacingSource::kImageJResolution);
  EXPECT_EQ(v.spacing.source[2], SpacingSource::kImageJSpacing);
}

TEST(TiffStackSpacing, ImageJNanometreUnit) {
  ScratchDir dir;
  Fixture f;
  f.description = "ImageJ=1.11a\nimages=3\nslices=3\nspacing=500\nunit=nm\n";
  f.x_resolution = 0.01f, f.y_resolution = 0.02f;  // pixels per nm
  write_fixture(dir / "ij.tif", f);
  const Volume v = read_tiff_stack(dir / "ij.tif");
  EXPECT_NEAR(v.spacing.um[0], 0.1, 1e-7);
  EXPECT_NEAR(v.spacing.um[1], 0.05, 1e-7);
  EXPECT_DOUBLE_EQ(v.spacing.um[2], 0.5);
}

TEST(TiffStackSpacing, OmeXmlPhysicalSizeInNanometres) {
  ScratchDir dir;
  Fixture f;
  f.description =
      "<OME><Image><Pixels DimensionOrder='XYZCT' SizeX='7' SizeY='5' SizeZ='3' SizeC='1' SizeT='1' "
      "PhysicalSizeX='250' PhysicalSizeXUnit='nm' PhysicalSizeY='0.3' PhysicalSizeZ='2000' "
      "PhysicalSizeZUnit='nm'/></Image></OME>";
  f.x_resolution = 10.0f, f.y_resolution = 10.0f, f.resolution_unit = RESUNIT_CENTIMETER;  // loses to OME
  write_fixture(dir / "ome.tif", f);
  const Volume v = read_tiff_stack(dir / "ome.tif");
  EXPECT_DOUBLE_EQ(v.spacing.um[0], 0.25);
  EXPECT_DOUBLE_EQ(v.spacing.um[1], 0.3);  // PhysicalSizeYUnit defaults to µm
  EXPECT_DOUBLE_EQ(v.spacing.um[2], 2.0);
  for (std::size_t a = 0; a < 3; ++a) EXPECT_EQ(v.spacing.source[a], SpacingSource::kOmeXml);
}

TEST(TiffStackSpacing, UserOverrideWins) {
  ScratchDir dir;
  Fixture f;
  f.description = "ImageJ=1.11a\nimages=3\nslices=3\nspacing=0.9988\nunit=um\n";
  f.x_resolution = 3.0336f, f.y_resolution = 3.0336f;
  write_fixture(dir / "ij.tif", f);
  const Volume v = read_tiff_stack(dir / "ij.tif", {.spacing_um = std::array<double, 3>{0.1, 0.2, 0.3}});
  EXPECT_EQ(v.spacing.um, (std::array<double, 3>{0.1, 0.2, 0.3}));
  for (std::size_t a = 0; a < 3; ++a) EXPECT_EQ(v.spacing.source[a], SpacingSource::kUser);
}

TEST(TiffStackSpacing, UserOverrideBypassesBrokenCalibration) {
  ScratchDir dir;
  Fixture f;
  f.description = "ImageJ=1.11a\nimages=3\nslices=3\nspacing=abc\nunit=um\n";
  write_fixture(dir / "ij.tif", f);
  expect_input_error(dir / "ij.tif", "spacing=abc is not a number");
  EXPECT_NO_THROW((void)read_tiff_stack(dir / "ij.tif", {.spacing_um = std::array<double, 3>{1, 1, 1}}));
}

TEST(TiffStackSpacing, NothingStoredIsOneMicronDefault) {
  ScratchDir dir;
  Fixture f;
  write_fixture(dir / "plain.tif", f);
  const Volume v = read_tiff_stack(dir / "plain.tif");
  for (std::size_t a = 0; a < 3; ++a) {
    EXPECT_EQ(v.spacing.um[a], 1.0);
    EXPECT_EQ(v.spacing.source[a], SpacingSource::kDefault);
  }
}

TEST(TiffStackSpacing, CentimetreResolutionIsUsed) {
  ScratchDir dir;
  Fixture f;
  f.x_resolution = 20000.0f, f.y_resolution = 40000.0f, f.resolution_unit = RESUNIT_CENTIMETER;
  write_fixture(dir / "cm.tif", f);
  const Volume v = read_tiff_stack(dir / "cm.tif");
  EXPECT_NEAR(v.spacing.um[0], 0.5, 1e-9);
  EXPECT_NEAR(v.spacing.um[1], 0.25, 1e-9);
  EXPECT_EQ(v.spacing.source[0], SpacingSource::kTiffResolution);
  EXPECT_EQ(v.spacing.source[2], SpacingSource::kDefault);
}

TEST(TiffStackSpacing, InchResolutionIsDisplayDpiAndIgnored) {
  ScratchDir dir;
  Fixture f;
  f.x_resolution = 300.0f, f.y_resolution = 300.0f, f.resolution_unit = RESUNIT_INCH;
  write_fixture(dir / "dpi.tif", f);
  const Volume v = read_tiff_stack(dir / "dpi.tif");
  EXPECT_EQ(v.spacing.um[0], 1.0);
  EXPECT_EQ(v.spacing.source[0], SpacingSource::kDefault);
}

// ---------------------------------------------------------------------------
// Inspection.

TEST(TiffStackInspect, ReportsHeaderWithoutDecoding) {
  ScratchDir dir;
  Fixture f;
  f.nx = 12, f.ny = 9, f.pages = 5, f.bits = 16, f.compression = COMPRESSION_ADOBE_DEFLATE;
  f.description = "ImageJ=1.11a\nimages=5\nslices=5\nspacing=2\nunit=micron\n";
  f.x_resolution = 2.0f, f.y_resolution = 4.0f;
  write_fixture(dir / "i.tif", f);
  const TiffStackInfo info = inspect_tiff_stack(dir / "i.tif");
  EXPECT_EQ(info.nx, 12);
  EXPECT_EQ(info.ny, 9);
  EXPECT_EQ(info.nz, 5);
  EXPECT_EQ(info.pages, 5);
  EXPECT_EQ(info.channels, 1);
  EXPECT_EQ(info.type, SampleType::kUint16);
  EXPECT_EQ(info.compression, "AdobeDeflate");
  EXPECT_FALSE(info.tiled);
  EXPECT_FALSE(info.bigtiff);
  EXPECT_DOUBLE_EQ(info.spacing.um[0], 0.5);
  EXPECT_DOUBLE_EQ(info.spacing.um[1], 0.25);
  EXPECT_DOUBLE_EQ(info.spacing.um[2], 2.0);
}

// ---------------------------------------------------------------------------
// Bad inputs: each an InputError of one line naming the path, nothing on stderr.

TEST(TiffStackBadInput, TextFile) {
  ScratchDir dir;
  hisnegs::testing::write_text(dir / "notes.tif", "this is not a TIFF file\n");
  expect_input_error(dir / "notes.tif", "is not a readable TIFF file");
}

TEST(TiffStackBadInput, EmptyFile) {
  ScratchDir dir;
  hisnegs::testing::write_text(dir / "empty.tif", "");
  expect_input_error(dir / "empty.tif", "is not a readable TIFF file");
}

TEST(TiffStackBadInput, TruncatedFile) {
  ScratchDir dir;
  Fixture f;
  f.nx = 64, f.ny = 64, f.pages = 6;
  write_fixture(dir / "full.tif", f);
  const auto size = fs::file_size(dir / "full.tif");
  fs::copy_file(dir / "full.tif", dir / "half.tif");
  fs::resize_file(dir / "half.tif", size / 2);
  expect_input_error(dir / "half.tif", "");
}

TEST(TiffStackBadInput, CorruptCompressedData) {
  ScratchDir dir;
  Fixture f;
  f.nx = 64, f.ny = 64, f.compression = COMPRESSION_ADOBE_DEFLATE;
  write_fixture(dir / "z.tif", f);
  {
    // libtiff writes page 0's strip right after the 8-byte header.
    std::fstream file(dir / "z.tif", std::ios::in | std::ios::out | std::ios::binary);
    file.seekp(12);
    const std::string garbage(24, '\xff');
    file.write(garbage.data(), static_cast<std::streamsize>(garbage.size()));
  }
  expect_input_error(dir / "z.tif", "cannot decode page 0");
}

TEST(TiffStackBadInput, TruncatedInsideTheHeader) {
  ScratchDir dir;
  Fixture f;
  write_fixture(dir / "full.tif", f);
  fs::copy_file(dir / "full.tif", dir / "cut.tif");
  fs::resize_file(dir / "cut.tif", 6);
  expect_input_error(dir / "cut.tif", "is not a readable TIFF file");
}

TEST(TiffStackBadInput, SinglePage) {
  ScratchDir dir;
  Fixture f;
  f.pages = 1;
  write_fixture(dir / "one.tif", f);
  expect_input_error(dir / "one.tif", "is a single 2D image (1 page); expected a 3D stack");
  EXPECT_EQ(inspect_tiff_stack(dir / "one.tif").nz, 1);  // info still describes it
}

TEST(TiffStackBadInput, RgbWithoutChannel) {
  ScratchDir dir;
  Fixture f;
  f.samples = 3, f.photometric = PHOTOMETRIC_RGB;
  write_fixture(dir / "rgb.tif", f);
  expect_input_error(dir / "rgb.tif", "has 3 channels; choose one with --channel (0..2)");
}

void write_float_with(const fs::path& path, float bad) {
  Fixture f;
  f.bits = 32, f.sample_format = SAMPLEFORMAT_IEEEFP;
  f.value = [bad](int page, int, int x, int y) {
    return (page == 2 && x == 4 && y == 3) ? static_cast<double>(bad) : 0.5;
  };
  write_fixture(path, f);
}

TEST(TiffStackBadInput, NaNInFloatStack) {
  ScratchDir dir;
  write_float_with(dir / "nan.tif", std::numeric_limits<float>::quiet_NaN());
  expect_input_error(dir / "nan.tif", "voxel (x=4, y=3, z=2) is NaN");
}

TEST(TiffStackBadInput, InfInFloatStack) {
  ScratchDir dir;
  write_float_with(dir / "inf.tif", -std::numeric_limits<float>::infinity());
  expect_input_error(dir / "inf.tif", "voxel (x=4, y=3, z=2) is -Inf");
}

TEST(TiffStackBadInput, SignedSixteenBit) {
  ScratchDir dir;
  Fixture f;
  f.bits = 16, f.sample_format = SAMPLEFORMAT_INT;
  write_fixture(dir / "s16.tif", f);
  expect_input_error(dir / "s16.tif",
                     "unsupported sample format: 16-bit signed integer; expected 8/16-bit unsigned or 32-bit float");
}

TEST(TiffStackBadInput, SixtyFourBitFloat) {
  ScratchDir dir;
  Fixture f;
  f.bits = 64, f.sample_format = SAMPLEFORMAT_IEEEFP;
  write_fixture(dir / "f64.tif", f);
  expect_input_error(dir / "f64.tif", "64-bit float");
}

TEST(TiffStackBadInput, MinIsWhite) {
  ScratchDir dir;
  Fixture f;
  f.photometric = PHOTOMETRIC_MINISWHITE;
  write_fixture(dir / "white.tif", f);
  expect_input_error(dir / "white.tif", "min-is-white");
}

TEST(TiffStackBadInput, MissingPath) {
  ScratchDir dir;
  expect_input_error(dir / "nope.tif", "no such file");
}

TEST(TiffStackBadInput, Directory) {
  ScratchDir dir;
  fs::create_directory(dir / "folder.tif");
  expect_input_error(dir / "folder.tif", "is a directory");
}

TEST(TiffStackBadInput, PagesOfDifferentSize) {
  ScratchDir dir;
  const fs::path path = dir / "mixed.tif";
  TIFF* tif = TIFFOpen(path.c_str(), "w");
  ASSERT_NE(tif, nullptr);
  for (int page = 0; page < 3; ++page) {
    const std::uint32_t w = page == 2 ? 6 : 5;
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, w);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 4u);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 8);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
    TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 4u);
    std::vector<unsigned char> data(w * 4, 1);
    ASSERT_GT(TIFFWriteEncodedStrip(tif, 0, data.data(), static_cast<tmsize_t>(data.size())), 0);
    ASSERT_TRUE(TIFFWriteDirectory(tif));
  }
  TIFFClose(tif);
  expect_input_error(path, "page 2 is 6x4");
}

TEST(TiffStackBadInput, TimeSeries) {
  ScratchDir dir;
  Fixture f;
  f.pages = 4;
  f.description = "ImageJ=1.11a\nimages=4\nslices=2\nframes=2\nhyperstack=true\n";
  write_fixture(dir / "t.tif", f);
  expect_input_error(dir / "t.tif", "has 2 time points");
}

TEST(TiffStackBadInput, HostileCountsInMetadataDoNotOverflow) {
  ScratchDir dir;
  Fixture f;
  f.description =
      "<OME><Pixels SizeX='7' SizeY='5' SizeZ='2000000000' SizeC='2000000000' SizeT='2000000000' "
      "DimensionOrder='XYZCT'/></OME>";
  write_fixture(dir / "ome.tif", f);
  expect_input_error(dir / "ome.tif", "OME-XML describes 8e+27 planes");
  f.description = "ImageJ=1.11a\nimages=3\nchannels=2000000000\nslices=2000000000\nframes=2000000000\n";
  write_fixture(dir / "ij.tif", f);
  expect_input_error(dir / "ij.tif", "does not equal images=3");
}

TEST(TiffStackBadInput, ImageCountDisagreesWithPages) {
  ScratchDir dir;
  Fixture f;
  f.pages = 3;
  f.description = "ImageJ=1.11a\nimages=5\nslices=5\n";
  write_fixture(dir / "c.tif", f);
  expect_input_error(dir / "c.tif", "images=5 but the file has 3 pages");
}

// Sets HISNEGS_MAX_ALLOC_GB for one scope.
class AllocLimit {
 public:
  explicit AllocLimit(const char* gib) { ::setenv("HISNEGS_MAX_ALLOC_GB", gib, 1); }
  ~AllocLimit() { ::unsetenv("HISNEGS_MAX_ALLOC_GB"); }
  AllocLimit(const AllocLimit&) = delete;
  AllocLimit& operator=(const AllocLimit&) = delete;
};

TEST(TiffStackBadInput, VolumeOverTheMemoryLimit) {
  ScratchDir dir;
  Fixture f;
  f.nx = 64, f.ny = 64, f.pages = 4;
  write_fixture(dir / "big.tif", f);
  {
    const AllocLimit limit("0.00001");  // ~10 KiB < 64 KiB of floats
    expect_input_error(dir / "big.tif", "would need 0.00 GiB for 64x64x4 float32 voxels but the limit is");
  }
  EXPECT_NO_THROW((void)read_tiff_stack(dir / "big.tif"));
}

// A few bytes claiming 60000 x 60000 x 2 pages of 8-bit (26.8 GiB as float32).
// Uncompressed, the strip table itself gives it away before anything is
// allocated; deflated (any size is possible), the allocation limit refuses it.
void write_hostile_header(const fs::path& path, std::uint16_t compression) {
  TIFF* tif = TIFFOpen(path.c_str(), "w");
  ASSERT_NE(tif, nullptr);
  for (int page = 0; page < 2; ++page) {
    TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, 60000u);
    TIFFSetField(tif, TIFFTAG_IMAGELENGTH, 60000u);
    TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, 8);
    TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, 1);
    TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
    TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, 60000u);
    TIFFSetField(tif, TIFFTAG_COMPRESSION, compression);
    unsigned char bytes[16] = {};
    ASSERT_GT(TIFFWriteRawStrip(tif, 0, bytes, sizeof bytes), 0);
    ASSERT_TRUE(TIFFWriteDirectory(tif));
  }
  TIFFClose(tif);
}

TEST(TiffStackBadInput, HostileHeaderIsRefusedBeforeAllocating) {
  ScratchDir dir;
  const AllocLimit limit("1");
  write_hostile_header(dir / "plain.tif", COMPRESSION_NONE);
  expect_input_error(dir / "plain.tif", "truncated or damaged");
  write_hostile_header(dir / "deflated.tif", COMPRESSION_ADOBE_DEFLATE);
  expect_input_error(dir / "deflated.tif",
                     "would need 26.82 GiB for 60000x60000x2 float32 voxels but the limit is 1.00 GiB");
}

TEST(TiffStackBadInput, MalformedMemoryLimit) {
  ScratchDir dir;
  Fixture f;
  write_fixture(dir / "a.tif", f);
  const AllocLimit limit("lots");
  EXPECT_THROW((void)read_tiff_stack(dir / "a.tif"), InputError);
}

TEST(TiffStackBadInput, InvalidOptions) {
  EXPECT_THROW(TiffReadOptions{.channel = -1}.validate(), InputError);
  EXPECT_THROW((TiffReadOptions{.spacing_um = std::array<double, 3>{1, std::nan(""), 1}}.validate()), InputError);
  EXPECT_NO_THROW((TiffReadOptions{.channel = 0, .spacing_um = std::array<double, 3>{1, 2, 3}}.validate()));
}

}  // namespace
}  // namespace hisnegs::io
