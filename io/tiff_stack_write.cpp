// SPDX-License-Identifier: Apache-2.0
// TIFF stack writing on libtiff: float32 / uint8 / uint16 pages with ImageJ
// metadata, checked values (never clamped), atomic (temp file + rename).
#include <fcntl.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

#include "io/atomic_file.hpp"
#include "io/detail/tiff_handle.hpp"
#include "io/error.hpp"
#include "io/tiff_stack.hpp"

namespace hisnegs::io {
namespace fs = std::filesystem;
using detail::bytes_of;
using detail::kGiB;
using detail::non_finite_text;
using detail::TiffHandle;

void TiffWriteOptions::validate() const {
  TiffReadOptions spacing_check;
  spacing_check.spacing_um = spacing_um;
  spacing_check.validate();
}

namespace {

// Checks that every value can be stored as `type` without change; throws
// InputError naming the first voxel that cannot. Returns (min, max).
std::pair<float, float> check_writable(const fs::path& path, std::span<const float> voxels, int nx, int ny,
                                       SampleType type) {
  const double hi = type == SampleType::kUint8 ? 255.0 : 65535.0;
  float lo_seen = std::numeric_limits<float>::infinity(), hi_seen = -lo_seen;
  for (std::size_t i = 0; i < voxels.size(); ++i) {
    const float v = voxels[i];
    std::string problem;
    if (!std::isfinite(v)) {
      problem = std::string(non_finite_text(v)) + "; TIFF stacks must hold finite values";
    } else if (type != SampleType::kFloat32 && (v < 0 || v > hi || v != std::floor(v))) {
      problem = std::to_string(v) + ", which does not fit " + std::string(to_string(type)) + " (integers 0.." +
                std::to_string(static_cast<int>(hi)) + "); values are never clamped or rounded";
    }
    if (!problem.empty()) {
      const std::size_t plane = static_cast<std::size_t>(nx) * ny;
      fail_input(path, "voxel (x=" + std::to_string(i % nx) + ", y=" + std::to_string(i % plane / nx) +
                           ", z=" + std::to_string(i / plane) + ") is " + problem);
    }
    lo_seen = std::min(lo_seen, v);
    hi_seen = std::max(hi_seen, v);
  }
  return {lo_seen, hi_seen};
}

// Shortest text that parses back to exactly `v` ("0.9988", not "0.99880000000000002").
template <class T>
std::string shortest_text(T v) {
  char text[64];
  const auto result = std::to_chars(text, text + sizeof text, v);
  return std::string(text, result.ptr);
}

template <class T>
void pack_samples(const float* src, std::size_t count, unsigned char* dst) {
  for (std::size_t i = 0; i < count; ++i) {
    const T v = static_cast<T>(src[i]);
    std::memcpy(dst + i * sizeof(T), &v, sizeof(T));
  }
}

void check_shape(std::span<const float> voxels, int nx, int ny, int nz) {
  if (nx < 1 || ny < 1 || nz < 1) {
    throw std::invalid_argument("write_tiff_stack: shape " + std::to_string(nx) + "x" + std::to_string(ny) + "x" +
                                std::to_string(nz) + " must be at least 1x1x1");
  }
  if (voxels.size() != static_cast<std::size_t>(nx) * ny * nz) {
    throw std::invalid_argument("write_tiff_stack: " + std::to_string(voxels.size()) + " voxels for shape " +
                                std::to_string(nx) + "x" + std::to_string(ny) + "x" + std::to_string(nz));
  }
}

// The ImageJ description of the first page: slice count, z spacing, display range.
// `images=` promises readers the pages' data lies back to back from page 0's
// (ImageJ and tifffile read it as one block): only written when it does.
std::string imagej_description(int nz, const TiffWriteOptions& options, double lo, double hi, bool contiguous) {
  std::string description = "ImageJ=1.11a\n";
  if (contiguous) description += "images=" + std::to_string(nz) + "\n";
  description += "slices=" + std::to_string(nz) + "\n";
  if (options.spacing_um) description += "unit=um\nspacing=" + shortest_text((*options.spacing_um)[2]) + "\n";
  description += "min=" + shortest_text(lo) + "\nmax=" + shortest_text(hi) + "\n";
  return description;
}

// The tags of one page (the description only on the first).
void set_page_tags(TIFF* tif, int nx, int ny, std::size_t rows_per_strip, const TiffWriteOptions& options,
                   const std::string* description) {
  TIFFSetField(tif, TIFFTAG_SUBFILETYPE, 0);
  TIFFSetField(tif, TIFFTAG_IMAGEWIDTH, static_cast<std::uint32_t>(nx));
  TIFFSetField(tif, TIFFTAG_IMAGELENGTH, static_cast<std::uint32_t>(ny));
  TIFFSetField(tif, TIFFTAG_BITSPERSAMPLE, static_cast<std::uint16_t>(8 * bytes_of(options.type)));
  TIFFSetField(tif, TIFFTAG_SAMPLESPERPIXEL, static_cast<std::uint16_t>(1));
  TIFFSetField(tif, TIFFTAG_SAMPLEFORMAT,
               options.type == SampleType::kFloat32 ? SAMPLEFORMAT_IEEEFP : SAMPLEFORMAT_UINT);
  TIFFSetField(tif, TIFFTAG_PHOTOMETRIC, PHOTOMETRIC_MINISBLACK);
  TIFFSetField(tif, TIFFTAG_PLANARCONFIG, PLANARCONFIG_CONTIG);
  TIFFSetField(tif, TIFFTAG_ROWSPERSTRIP, static_cast<std::uint32_t>(rows_per_strip));
  if (options.deflate) {
    TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_ADOBE_DEFLATE);
    // Horizontal differencing helps integer images a lot and every reader has
    // it; the floating-point predictor is left out because ImageJ lacks it.
    if (options.type != SampleType::kFloat32) TIFFSetField(tif, TIFFTAG_PREDICTOR, PREDICTOR_HORIZONTAL);
  } else {
    TIFFSetField(tif, TIFFTAG_COMPRESSION, COMPRESSION_NONE);
  }
  if (options.spacing_um) {
    // ImageJ calibration: pixels per `unit`, ResolutionUnit none.
    TIFFSetField(tif, TIFFTAG_XRESOLUTION, 1.0 / (*options.spacing_um)[0]);
    TIFFSetField(tif, TIFFTAG_YRESOLUTION, 1.0 / (*options.spacing_um)[1]);
    TIFFSetField(tif, TIFFTAG_RESOLUTIONUNIT, RESUNIT_NONE);
  }
  if (description) TIFFSetField(tif, TIFFTAG_IMAGEDESCRIPTION, description->c_str());
  TIFFSetField(tif, TIFFTAG_SOFTWARE, "hisnegs");
}

// Packs and writes one page strip by strip; false when libtiff refuses a strip.
bool write_page_strips(TIFF* tif, const float* page, int nx, int ny, std::size_t rows_per_strip, SampleType type,
                       std::vector<unsigned char>& strip) {
  const std::size_t bytes = bytes_of(type);
  for (std::size_t row = 0, s = 0; row < static_cast<std::size_t>(ny); row += rows_per_strip, ++s) {
    const std::size_t rows = std::min(rows_per_strip, static_cast<std::size_t>(ny) - row);
    const std::size_t count = rows * static_cast<std::size_t>(nx);
    const float* src = page + row * static_cast<std::size_t>(nx);
    switch (type) {
      case SampleType::kUint8:
        pack_samples<std::uint8_t>(src, count, strip.data());
        break;
      case SampleType::kUint16:
        pack_samples<std::uint16_t>(src, count, strip.data());
        break;
      case SampleType::kFloat32:
        pack_samples<float>(src, count, strip.data());
        break;
    }
    const auto size = static_cast<tmsize_t>(count * bytes);
    if (TIFFWriteEncodedStrip(tif, static_cast<std::uint32_t>(s), strip.data(), size) != size) return false;
  }
  return true;
}

}  // namespace

void write_tiff_stack(const fs::path& path, std::span<const float> voxels, int nx, int ny, int nz,
                      const TiffWriteOptions& options) {
  options.validate();
  check_shape(voxels, nx, ny, nz);
  const auto [lo, hi] = check_writable(path, voxels, nx, ny, options.type);
  const std::size_t page_voxels = static_cast<std::size_t>(nx) * ny;
  const std::size_t bytes = bytes_of(options.type);
  const std::size_t row_bytes = static_cast<std::size_t>(nx) * bytes;
  // Classic TIFF offsets are 32-bit; leave room for IFDs and the description.
  const bool bigtiff = static_cast<double>(voxels.size()) * bytes > 3.5 * kGiB;
  // Uncompressed (the default): one strip per page, every IFD first and then the
  // pages' data back to back, so the data is contiguous as the ImageJ description's
  // images= promises (ImageJ and tifffile then read the stack from page 0's offset;
  // with an IFD between pages, tifffile 2023 read a 2-page float stack as values up to
  // 1.9e28). libtiff writes it with deferred strip arrays (TIFFDeferStrileArrayWriting).
  // Deflate: pages of up to ~8 MiB strips, each followed by its IFD, and no images=
  // promise (compressed data is never read as one block).
  const bool contiguous = !options.deflate;
  const std::size_t rows_per_strip =
      contiguous ? static_cast<std::size_t>(ny)
                 : std::clamp<std::size_t>((std::size_t{8} << 20) / row_bytes, 1, static_cast<std::size_t>(ny));
  const std::string description = imagej_description(nz, options, lo, hi, contiguous);

  AtomicFile file(path);
  const int fd = ::open(file.temp_path().c_str(), O_RDWR | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
  if (fd < 0) fail_input(path, std::string("cannot open for writing: ") + std::strerror(errno));
  errno = 0;
  TiffHandle handle(fd, path, bigtiff ? "w8" : "w", 0);
  TIFF* tif = handle.get();
  auto fail_write = [&](const std::string& what) {
    const int err = errno;  // of the failing write(2): ENOSPC, EIO, EFBIG
    throw WriteError(describe(path, "cannot write " + what + (err ? std::string(": ") + std::strerror(err) : "") +
                                        handle.detail()));
  };
  // Opening writes the header into the temporary this process just created: a
  // failure there is a failed write (a full disk), not bad input.
  if (!tif) fail_write("the TIFF header");
  errno = 0;
  std::vector<unsigned char> strip(rows_per_strip * row_bytes);
  const auto page = [&](int z) { return voxels.data() + static_cast<std::size_t>(z) * page_voxels; };
  for (int z = 0; z < nz; ++z) {
    set_page_tags(tif, nx, ny, rows_per_strip, options, z == 0 ? &description : nullptr);
    if (contiguous) {
      if (!TIFFDeferStrileArrayWriting(tif) || !TIFFWriteCheck(tif, 0, path.c_str())) {
        fail_write("the directory of page " + std::to_string(z));
      }
    } else if (!write_page_strips(tif, page(z), nx, ny, rows_per_strip, options.type, strip)) {
      fail_write("page " + std::to_string(z));
    }
    if (!TIFFWriteDirectory(tif)) fail_write("the directory of page " + std::to_string(z));
  }
  if (contiguous) {  // back to each directory in turn: its data, then its strip offset and size
    for (int z = 0; z < nz; ++z) {
      if (!(z == 0 ? TIFFSetDirectory(tif, 0) : TIFFReadDirectory(tif))) {
        fail_write("the directory of page " + std::to_string(z));
      }
      if (!write_page_strips(tif, page(z), nx, ny, rows_per_strip, options.type, strip) ||
          !TIFFForceStrileArrayWriting(tif)) {
        fail_write("page " + std::to_string(z));
      }
    }
  }
  handle.close();
  if (handle.messages().errors > 0) fail_write("the file");
  file.commit();
}

void write_tiff_stack(const fs::path& path, const Volume& volume, const TiffWriteOptions& options) {
  TiffWriteOptions effective = options;
  const bool known = std::any_of(volume.spacing.source.begin(), volume.spacing.source.end(),
                                 [](SpacingSource s) { return s != SpacingSource::kDefault; });
  if (!effective.spacing_um && known) effective.spacing_um = volume.spacing.um;
  write_tiff_stack(path, volume.voxels, volume.nx, volume.ny, volume.nz, effective);
}

}  // namespace hisnegs::io
