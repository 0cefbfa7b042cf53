// SPDX-License-Identifier: Apache-2.0
// TIFF stack reading and inspection on libtiff: page layout, channel selection, decoding into float32.
// Writing is tiff_stack_write.cpp, the libtiff handle detail/tiff_handle.cpp, metadata text detail/tiff_metadata.cpp.
#include "io/tiff_stack.hpp"

#include <fcntl.h>
#include <tiffio.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

#include "io/atomic_file.hpp"
#include "io/detail/tiff_handle.hpp"
#include "io/detail/tiff_metadata.hpp"
#include "io/error.hpp"
#include "io/memory_limit.hpp"

namespace hisnegs::io {
namespace fs = std::filesystem;
using detail::bytes_of;
using detail::kGiB;
using detail::non_finite_text;
using detail::TiffHandle;

namespace {

// ---------------------------------------------------------------------------
// Memory limit for hostile headers.

// An integer-valued count held in a double: exact digits while the double is
// exact, else 3 significant digits ("8e+27") rather than spurious ones.
std::string count_text(double count) {
  char text[64];
  std::snprintf(text, sizeof text, count < 9e15 ? "%.0f" : "%.3g", count);
  return text;
}

// ---------------------------------------------------------------------------
// Page format.

// What every page must share with the first one.
struct PageFormat {
  std::uint32_t width = 0, height = 0;
  std::uint16_t bits = 0, sample_format = SAMPLEFORMAT_UINT, samples = 1;
  std::uint16_t photometric = PHOTOMETRIC_MINISBLACK;
  bool operator==(const PageFormat&) const = default;
};

PageFormat read_page_format(TIFF* tif) {
  PageFormat f;
  TIFFGetField(tif, TIFFTAG_IMAGEWIDTH, &f.width);
  TIFFGetField(tif, TIFFTAG_IMAGELENGTH, &f.height);
  TIFFGetFieldDefaulted(tif, TIFFTAG_BITSPERSAMPLE, &f.bits);
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLEFORMAT, &f.sample_format);
  // "void" (undefined) data is read as unsigned, as libtiff's default does.
  if (f.sample_format == SAMPLEFORMAT_VOID) f.sample_format = SAMPLEFORMAT_UINT;
  TIFFGetFieldDefaulted(tif, TIFFTAG_SAMPLESPERPIXEL, &f.samples);
  if (!TIFFGetField(tif, TIFFTAG_PHOTOMETRIC, &f.photometric)) f.photometric = PHOTOMETRIC_MINISBLACK;
  return f;
}

std::string photometric_text(std::uint16_t photometric) {
  switch (photometric) {
    case PHOTOMETRIC_MINISBLACK:
      return "min-is-black grey";
    case PHOTOMETRIC_MINISWHITE:
      return "min-is-white (inverted grey)";
    case PHOTOMETRIC_RGB:
      return "RGB";
    case PHOTOMETRIC_PALETTE:
      return "palette colour";
    case PHOTOMETRIC_YCBCR:
      return "YCbCr";
    case PHOTOMETRIC_SEPARATED:
      return "separated (CMYK)";
    default:
      return "photometric " + std::to_string(photometric);
  }
}

std::string sample_format_text(const PageFormat& f) {
  const std::string bits = std::to_string(f.bits) + "-bit ";
  switch (f.sample_format) {
    case SAMPLEFORMAT_UINT:
      return bits + "unsigned integer";
    case SAMPLEFORMAT_INT:
      return bits + "signed integer";
    case SAMPLEFORMAT_IEEEFP:
      return bits + "float";
    case SAMPLEFORMAT_COMPLEXINT:
      return bits + "complex integer";
    case SAMPLEFORMAT_COMPLEXIEEEFP:
      return bits + "complex float";
    default:
      return bits + "sample format " + std::to_string(f.sample_format);
  }
}

std::string format_text(const PageFormat& f) {
  return std::to_string(f.width) + "x" + std::to_string(f.height) + ", " + sample_format_text(f) + ", " +
         photometric_text(f.photometric) + ", " + std::to_string(f.samples) + " sample(s) per pixel";
}

SampleType sample_type_of(const fs::path& path, const PageFormat& f) {
  const bool unsigned_int = f.sample_format == SAMPLEFORMAT_UINT;
  if (unsigned_int && f.bits == 8) return SampleType::kUint8;
  if (unsigned_int && f.bits == 16) return SampleType::kUint16;
  if (f.sample_format == SAMPLEFORMAT_IEEEFP && f.bits == 32) return SampleType::kFloat32;
  fail_input(path,
             "unsupported sample format: " + sample_format_text(f) + "; expected 8/16-bit unsigned or 32-bit float");
}

void check_photometric(const fs::path& path, std::uint16_t photometric) {
  if (photometric == PHOTOMETRIC_MINISBLACK || photometric == PHOTOMETRIC_RGB) return;
  fail_input(path, "unsupported photometric interpretation: " + photometric_text(photometric) +
                       "; expected min-is-black grey or RGB");
}

// libtiff's codec name ("None", "LZW", "AdobeDeflate", ...) or "unknown (N)".
std::string compression_name(std::uint16_t compression) {
  if (const TIFFCodec* codec = TIFFFindCODEC(compression)) return codec->name;
  return "unknown (" + std::to_string(compression) + ")";
}

// ---------------------------------------------------------------------------
// Stack layout: which page holds (z, channel), from ImageJ / OME-XML / nothing.

struct StackLayout {
  PageFormat format;
  SampleType type = SampleType::kUint8;
  int pages = 0;          // IFDs in the file
  int page_channels = 1;  // channels stored as separate pages
  int nz = 0;
  int stride_z = 1;  // page = z * stride_z + page_channel * stride_c
  int stride_c = 0;
  VoxelSpacing spacing;
  std::string compression;
  bool tiled = false;
  bool bigtiff = false;
  [[nodiscard]] int channels() const { return format.samples * page_channels; }
};

// The page count and the first page's format, size, sample type and codec.
void read_first_page(TIFF* tif, const TiffHandle& handle, const fs::path& path, StackLayout& s) {
  const tdir_t pages = TIFFNumberOfDirectories(tif);
  // A broken IFD chain (a truncated file) ends the count early with an error:
  // never read a prefix of the stack as if it were all of it.
  if (handle.messages().errors > 0) fail_input(path, "is truncated or damaged" + handle.detail());
  if (pages == 0) fail_input(path, "has no readable pages" + handle.detail());
  if (pages > static_cast<tdir_t>(std::numeric_limits<int>::max())) fail_input(path, "has too many pages");
  s.pages = static_cast<int>(pages);
  s.format = read_page_format(tif);
  if (s.format.width == 0 || s.format.height == 0) {
    fail_input(path, "has an empty first page (" + std::to_string(s.format.width) + "x" +
                         std::to_string(s.format.height) + ")");
  }
  if (s.format.width > static_cast<std::uint32_t>(std::numeric_limits<int>::max()) ||
      s.format.height > static_cast<std::uint32_t>(std::numeric_limits<int>::max())) {
    fail_input(path, "has a page too large to index (" + std::to_string(s.format.width) + "x" +
                         std::to_string(s.format.height) + ")");
  }
  s.type = sample_type_of(path, s.format);
  check_photometric(path, s.format.photometric);
  if (s.format.samples == 0) fail_input(path, "has SamplesPerPixel = 0");
  std::uint32_t depth = 1;
  if (TIFFGetField(tif, TIFFTAG_IMAGEDEPTH, &depth) && depth > 1) {
    fail_input(path, "has volumetric tiles (ImageDepth = " + std::to_string(depth) + "), which are not supported");
  }
  std::uint16_t compression = COMPRESSION_NONE;
  TIFFGetFieldDefaulted(tif, TIFFTAG_COMPRESSION, &compression);
  s.compression = compression_name(compression);
  s.tiled = TIFFIsTiled(tif) != 0;
  s.bigtiff = TIFFIsBigTIFF(tif) != 0;
}

// The metadata text of the first page's ImageDescription: OME-XML or ImageJ.
struct StackDescription {
  std::optional<detail::OmePixels> ome;
  std::optional<detail::ImageJDescription> imagej;
};
StackDescription read_description(TIFF* tif, const fs::path& path) {
  StackDescription d;
  const char* description = nullptr;
  if (TIFFGetField(tif, TIFFTAG_IMAGEDESCRIPTION, &description) && description) {
    const std::string_view text(description);
    try {
      if (detail::is_ome_xml(text)) {
        d.ome = detail::parse_ome_pixels(text);
      } else if (detail::is_imagej_description(text)) {
        d.imagej = detail::parse_imagej_description(text);
      }
    } catch (const InputError& e) {
      fail_input(path, e.what());
    }
  }
  return d;
}

// Channel pages, Z and T counts of a stack. Counts are long long and their products
// are formed in double (exact below 2^53, and larger ones cannot match a page
// count): hostile descriptions must not overflow.
struct PageCounts {
  long long c_pages = 1, nz = 0, nt = 1;
};

// OME-XML: sizes must match the page, the planes must fit in the pages; strides
// from DimensionOrder (the letters after "XY" are ordered fastest first).
PageCounts ome_page_order(const detail::OmePixels& ome, const fs::path& path, StackLayout& s) {
  const long long samples = s.format.samples;
  if (static_cast<std::uint32_t>(ome.size_x) != s.format.width ||
      static_cast<std::uint32_t>(ome.size_y) != s.format.height) {
    fail_input(path, "OME-XML SizeX x SizeY = " + std::to_string(ome.size_x) + "x" + std::to_string(ome.size_y) +
                         " does not match the first page (" + std::to_string(s.format.width) + "x" +
                         std::to_string(s.format.height) + ")");
  }
  PageCounts n;
  // OME counts RGB samples in SizeC; such channels share a page.
  n.c_pages = (samples > 1 && ome.size_c % samples == 0) ? ome.size_c / samples : ome.size_c;
  n.nz = ome.size_z;
  n.nt = ome.size_time;
  const double planes = static_cast<double>(n.c_pages) * static_cast<double>(n.nz) * static_cast<double>(n.nt);
  if (planes > s.pages) {
    fail_input(path, "OME-XML describes " + count_text(planes) + " planes (SizeZ=" + std::to_string(n.nz) +
                         ", SizeC=" + std::to_string(ome.size_c) + ", SizeT=" + std::to_string(n.nt) +
                         ") but the file has " + std::to_string(s.pages) + " pages");
  }
  long long stride = 1, stride_z = 1, stride_c = 1;
  for (char axis : ome.dimension_order.substr(2)) {
    if (axis == 'Z') stride_z = stride, stride *= n.nz;
    if (axis == 'C') stride_c = stride, stride *= n.c_pages;
    if (axis == 'T') stride *= n.nt;
  }
  s.stride_z = static_cast<int>(stride_z);
  s.stride_c = static_cast<int>(stride_c);
  return n;
}

// ImageJ: channels x slices x frames must equal images, which must equal the pages;
// hyperstack order XYCZT: page = (t * Z + z) * C + c.
PageCounts imagej_page_order(const detail::ImageJDescription& imagej, const fs::path& path, StackLayout& s) {
  PageCounts n;
  n.c_pages = imagej.channels.value_or(1);
  n.nt = imagej.frames.value_or(1);
  const long long images = imagej.images.value_or(s.pages);
  if (imagej.slices) {
    n.nz = *imagej.slices;
  } else if (images % (n.c_pages * n.nt) == 0) {
    n.nz = images / (n.c_pages * n.nt);
  } else {
    n.nz = 0;  // reported as a mismatch below
  }
  if (static_cast<double>(n.c_pages) * static_cast<double>(n.nz) * static_cast<double>(n.nt) !=
      static_cast<double>(images)) {
    fail_input(path, "ImageJ description: channels=" + std::to_string(n.c_pages) + " x slices=" + std::to_string(n.nz) +
                         " x frames=" + std::to_string(n.nt) + " does not equal images=" + std::to_string(images));
  }
  if (images != s.pages) {
    fail_input(path, "ImageJ description says images=" + std::to_string(images) + " but the file has " +
                         std::to_string(s.pages) + " pages" +
                         (s.pages == 1 ? " (ImageJ's contiguous layout for files over 4 GiB is not "
                                         "supported; save as BigTIFF or OME-TIFF)"
                                       : ""));
  }
  s.stride_c = 1;
  s.stride_z = static_cast<int>(n.c_pages);
  return n;
}

// Which page holds (z, channel); refuses time series and out-of-range channels.
void resolve_page_order(const StackDescription& d, const fs::path& path, const TiffReadOptions& options,
                        StackLayout& s) {
  PageCounts n;
  n.nz = s.pages;
  if (d.ome) {
    n = ome_page_order(*d.ome, path, s);
  } else if (d.imagej) {
    n = imagej_page_order(*d.imagej, path, s);
  }
  if (n.nt > 1) {
    fail_input(path, "has " + std::to_string(n.nt) + " time points (" + (d.ome ? "OME SizeT" : "ImageJ frames") + "=" +
                         std::to_string(n.nt) + "); expected a single 3D stack");
  }
  if (n.c_pages * s.format.samples > std::numeric_limits<int>::max()) fail_input(path, "has too many channels");
  s.page_channels = static_cast<int>(n.c_pages);
  s.nz = static_cast<int>(n.nz);
  if (options.channel && *options.channel >= s.channels()) {
    fail_input(path, "channel " + std::to_string(*options.channel) + " is out of range: the file has " +
                         std::to_string(s.channels()) + " channel" + (s.channels() > 1 ? "s" : "") + " (0.." +
                         std::to_string(s.channels() - 1) + ")");
  }
}

// The voxel spacing by the CONVENTIONS precedence (option, OME, ImageJ, resolution tags).
void resolve_stack_spacing(TIFF* tif, const StackDescription& d, const fs::path& path, const TiffReadOptions& options,
                           StackLayout& s) {
  detail::SpacingEvidence evidence;
  evidence.user_um = options.spacing_um;
  evidence.ome = d.ome ? &*d.ome : nullptr;
  evidence.imagej = d.imagej ? &*d.imagej : nullptr;
  float x_res = 0, y_res = 0;
  std::uint16_t res_unit = RESUNIT_INCH;
  if (TIFFGetField(tif, TIFFTAG_XRESOLUTION, &x_res)) evidence.x_resolution = x_res;
  if (TIFFGetField(tif, TIFFTAG_YRESOLUTION, &y_res)) evidence.y_resolution = y_res;
  if (TIFFGetField(tif, TIFFTAG_RESOLUTIONUNIT, &res_unit)) evidence.resolution_unit = res_unit;
  try {
    s.spacing = detail::resolve_spacing(evidence);
  } catch (const InputError& e) {
    fail_input(path, std::string(e.what()) + "; pass the spacing explicitly (--spacing) to override");
  }
}

// Reads the header of the current (first) directory. Checks everything that
// inspect and read share; `options.channel` is only range-checked here.
StackLayout analyse_stack(TIFF* tif, const TiffHandle& handle, const fs::path& path, const TiffReadOptions& options) {
  StackLayout s;
  read_first_page(tif, handle, path, s);
  const StackDescription description = read_description(tif, path);
  resolve_page_order(description, path, options, s);
  resolve_stack_spacing(tif, description, path, options, s);
  return s;
}

// Opens `path` for reading after the file checks; throws InputError if libtiff refuses it.
std::unique_ptr<TiffHandle> open_for_read(const fs::path& path) {
  require_regular_file(path);
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) fail_input(path, std::string("cannot open: ") + std::strerror(errno));
  std::string limit_source;
  // "m": no memory-mapping: a mapped file counts in the resident set as its pages are
  // touched, which made a bricked fit of a file larger than --max-memory look larger.
  auto handle = std::make_unique<TiffHandle>(fd, path, "rm", allocation_limit_bytes(&limit_source));
  if (!handle->get()) fail_input(path, "is not a readable TIFF file" + handle->detail());
  return handle;
}

// ---------------------------------------------------------------------------
// Decoding.

// dst[i] = src[(i * stride + offset)] for i < count; memcpy keeps it alias-safe
// and unaligned-safe, and compiles to plain loads.
template <class T>
void convert_samples(const unsigned char* src, std::size_t stride, std::size_t offset, float* dst, std::size_t count) {
  src += offset * sizeof(T);
  for (std::size_t i = 0; i < count; ++i) {
    T v;
    std::memcpy(&v, src + i * stride * sizeof(T), sizeof(T));
    dst[i] = static_cast<float>(v);
  }
}

void convert(SampleType type, const unsigned char* src, std::size_t stride, std::size_t offset, float* dst,
             std::size_t count) {
  switch (type) {
    case SampleType::kUint8:
      convert_samples<std::uint8_t>(src, stride, offset, dst, count);
      break;
    case SampleType::kUint16:
      convert_samples<std::uint16_t>(src, stride, offset, dst, count);
      break;
    case SampleType::kFloat32:
      convert_samples<float>(src, stride, offset, dst, count);
      break;
  }
}

// The current page's strips or tiles must lie inside the file (`file_size` bytes),
// and an uncompressed page must hold all its pixels: checked before anything is
// allocated or decoded for it, so a tiny file claiming huge pages costs nothing.
void check_page_data(TIFF* tif, const fs::path& path, int page, const StackLayout& s, std::uint64_t file_size) {
  const bool tiled = TIFFIsTiled(tif) != 0;
  const char* unit = tiled ? "tile" : "strip";
  const std::uint32_t n = tiled ? TIFFNumberOfTiles(tif) : TIFFNumberOfStrips(tif);
  std::uint64_t* counts = nullptr;
  std::uint64_t* offsets = nullptr;
  if (n == 0 || !TIFFGetField(tif, tiled ? TIFFTAG_TILEBYTECOUNTS : TIFFTAG_STRIPBYTECOUNTS, &counts) ||
      !TIFFGetField(tif, tiled ? TIFFTAG_TILEOFFSETS : TIFFTAG_STRIPOFFSETS, &offsets) || !counts || !offsets) {
    fail_input(path, "page " + std::to_string(page) + " has no " + unit + " table (damaged)");
  }
  std::uint64_t total = 0;
  for (std::uint32_t i = 0; i < n; ++i) {
    if (offsets[i] > file_size || counts[i] > file_size - offsets[i]) {
      fail_input(path, "page " + std::to_string(page) + ": " + unit + " " + std::to_string(i) + " (bytes " +
                           std::to_string(offsets[i]) + " + " + std::to_string(counts[i]) +
                           ") lies beyond the end of the file (" + std::to_string(file_size) +
                           " bytes); truncated or damaged");
    }
    total += counts[i];
  }
  std::uint16_t compression = COMPRESSION_NONE;
  TIFFGetFieldDefaulted(tif, TIFFTAG_COMPRESSION, &compression);
  const double need = static_cast<double>(s.format.width) * s.format.height * s.format.samples * bytes_of(s.type);
  if (compression == COMPRESSION_NONE && static_cast<double>(total) < need) {
    fail_input(path, "page " + std::to_string(page) + " holds " + std::to_string(total) +
                         " bytes of uncompressed pixel data but " + format_text(s.format) + " needs " +
                         number_text(need) + "; truncated or damaged");
  }
}

// The part of a page a read needs, in pixels: [x0, x1) x [y0, y1).
struct PageWindow {
  std::uint32_t x0 = 0, x1 = std::numeric_limits<std::uint32_t>::max();
  std::uint32_t y0 = 0, y1 = std::numeric_limits<std::uint32_t>::max();
};

// A growable byte buffer reused for every strip/tile of the whole read.
class DecodeBuffer {
 public:
  unsigned char* reserve(const fs::path& path, double bytes) {
    if (bytes > static_cast<double>(size_)) {
      check_allocation(path, bytes, "one decoded strip or tile");
      data_.reset(new unsigned char[static_cast<std::size_t>(bytes)]);
      size_ = static_cast<std::size_t>(bytes);
    }
    return data_.get();
  }

 private:
  std::unique_ptr<unsigned char[]> data_;
  std::size_t size_ = 0;
};

// Decodes sample `sample` of the current directory (page `page`) into `dst` (ny*nx
// floats): the tiles or strips that meet `window` (all of them by default; the
// rest of dst is left as it was).
void decode_page(TIFF* tif, const TiffHandle& handle, const fs::path& path, int page, const StackLayout& s, int sample,
                 float* dst, DecodeBuffer& buffer, const PageWindow& window) {
  const std::size_t nx = s.format.width, ny = s.format.height;
  const std::size_t bytes = bytes_of(s.type);
  std::uint16_t compression = COMPRESSION_NONE;
  TIFFGetFieldDefaulted(tif, TIFFTAG_COMPRESSION, &compression);
  if (!TIFFIsCODECConfigured(compression)) {
    fail_input(path, "page " + std::to_string(page) + " uses compression scheme " + compression_name(compression) +
                         ", which this libtiff build cannot decode");
  }
  std::uint16_t planar = PLANARCONFIG_CONTIG;
  TIFFGetFieldDefaulted(tif, TIFFTAG_PLANARCONFIG, &planar);
  const bool separate = planar == PLANARCONFIG_SEPARATE && s.format.samples > 1;
  const auto plane = static_cast<std::uint16_t>(separate ? sample : 0);
  const std::size_t stride = separate ? 1 : s.format.samples;  // samples per pixel in the buffer
  const std::size_t offset = separate ? 0 : static_cast<std::size_t>(sample);
  auto fail_read = [&](const std::string& what) {
    fail_input(path, "cannot decode page " + std::to_string(page) + " " + what + handle.detail());
  };

  if (TIFFIsTiled(tif)) {
    std::uint32_t tw = 0, th = 0;
    TIFFGetField(tif, TIFFTAG_TILEWIDTH, &tw);
    TIFFGetField(tif, TIFFTAG_TILELENGTH, &th);
    if (tw == 0 || th == 0) fail_read("(tile size " + std::to_string(tw) + "x" + std::to_string(th) + ")");
    const double need = static_cast<double>(tw) * th * stride * bytes;
    unsigned char* buf = buffer.reserve(path, need);
    const auto need_bytes = static_cast<tmsize_t>(need);
    for (std::uint32_t ty = 0; ty < ny; ty += th) {
      if (ty >= window.y1 || ty + th <= window.y0) continue;
      for (std::uint32_t tx = 0; tx < nx; tx += tw) {
        if (tx >= window.x1 || tx + tw <= window.x0) continue;
        const std::uint32_t tile = TIFFComputeTile(tif, tx, ty, 0, plane);
        if (TIFFReadEncodedTile(tif, tile, buf, need_bytes) < need_bytes) {
          fail_read("tile " + std::to_string(tile));
        }
        const std::size_t rows = std::min<std::size_t>(th, ny - ty);
        const std::size_t cols = std::min<std::size_t>(tw, nx - tx);
        for (std::size_t r = 0; r < rows; ++r) {
          convert(s.type, buf + r * tw * stride * bytes, stride, offset, dst + (ty + r) * nx + tx, cols);
        }
      }
    }
    return;
  }

  std::uint32_t rows_per_strip = 0;
  TIFFGetFieldDefaulted(tif, TIFFTAG_ROWSPERSTRIP, &rows_per_strip);
  if (rows_per_strip == 0 || rows_per_strip > ny) rows_per_strip = static_cast<std::uint32_t>(ny);
  unsigned char* buf = buffer.reserve(path, static_cast<double>(rows_per_strip) * nx * stride * bytes);
  for (std::uint32_t row = 0; row < ny; row += rows_per_strip) {
    if (row >= window.y1 || row + rows_per_strip <= window.y0) continue;
    const std::size_t rows = std::min<std::size_t>(rows_per_strip, ny - row);
    const auto need = static_cast<tmsize_t>(rows * nx * stride * bytes);
    const std::uint32_t strip = TIFFComputeStrip(tif, row, plane);
    if (TIFFReadEncodedStrip(tif, strip, buf, need) < need) fail_read("strip " + std::to_string(strip));
    convert(s.type, buf, stride, offset, dst + row * nx, rows * nx);
  }
}

}  // namespace

// ---------------------------------------------------------------------------
// Public API.

void TiffReadOptions::validate() const {
  if (channel && *channel < 0) {
    throw InputError("channel = " + std::to_string(*channel) + " is invalid: must be >= 0");
  }
  if (spacing_um) {
    static const char* const kAxis[3] = {"x", "y", "z"};
    for (int a = 0; a < 3; ++a) {
      const double v = (*spacing_um)[static_cast<std::size_t>(a)];
      if (const std::string problem = voxel_size_problem(v); !problem.empty()) {
        throw InputError("spacing_um " + std::string(kAxis[a]) + " = " + number_text(v) + ": " + problem);
      }
    }
  }
}

TiffStackInfo inspect_tiff_stack(const fs::path& path, const TiffReadOptions& options) {
  options.validate();
  const std::unique_ptr<TiffHandle> handle = open_for_read(path);
  const StackLayout s = analyse_stack(handle->get(), *handle, path, options);
  TiffStackInfo info;
  info.nx = static_cast<int>(s.format.width);
  info.ny = static_cast<int>(s.format.height);
  info.nz = s.nz;
  info.channels = s.channels();
  info.type = s.type;
  info.spacing = s.spacing;
  info.compression = s.compression;
  info.tiled = s.tiled;
  info.bigtiff = s.bigtiff;
  info.pages = s.pages;
  return info;
}

namespace {

// Where page z (within the slab) is decoded, and what happens to it then.
struct PageSink {
  std::function<float*(int z)> target;
  std::function<void(int z, const float* page)> done;
};

// The stack's layout, checked before anything is allocated: channels, depth, the
// first page's data and an uncompressed stack's size against the file's.
struct CheckedStack {
  StackLayout s;
  std::uint64_t file_size = 0;
};
CheckedStack check_stack(TIFF* tif, const TiffHandle& handle, const fs::path& path, const TiffReadOptions& options) {
  options.validate();
  CheckedStack c;
  c.s = analyse_stack(tif, handle, path, options);
  const StackLayout& s = c.s;
  if (s.channels() > 1 && !options.channel) {
    fail_input(path, "has " + std::to_string(s.channels()) + " channels; choose one with --channel (0.." +
                         std::to_string(s.channels() - 1) + ")");
  }
  if (s.nz < 2) {
    if (s.pages == 1) fail_input(path, "is a single 2D image (1 page); expected a 3D stack");
    fail_input(path, "has a single Z slice (" + std::to_string(s.pages) + " pages, " + std::to_string(s.channels()) +
                         " channels); expected a 3D stack");
  }
  std::error_code size_error;
  c.file_size = fs::file_size(path, size_error);
  if (size_error) fail_input(path, "cannot read its size: " + size_error.message());
  check_page_data(tif, path, 0, s, c.file_size);  // before anything is allocated
  if (s.compression == compression_name(COMPRESSION_NONE)) {
    const double need =
        static_cast<double>(s.format.width) * s.format.height * s.format.samples * bytes_of(s.type) * s.nz;
    if (need > static_cast<double>(c.file_size)) {
      fail_input(path, "claims " + std::to_string(s.nz) + " uncompressed pages of " + format_text(s.format) + " (" +
                           gib_text(need) + ") but the file has " + std::to_string(c.file_size) +
                           " bytes; truncated or damaged");
    }
  }
  return c;
}

// Moves to page `page` (> 0) by the chain from the current one, and checks that it
// matches page 0's format.
void next_page(TIFF* tif, const TiffHandle& handle, const fs::path& path, int page, const StackLayout& s) {
  if (!TIFFReadDirectory(tif) || handle.messages().errors > 0) {
    fail_input(path, "cannot read page " + std::to_string(page) + " of " + std::to_string(s.pages) + handle.detail());
  }
  const PageFormat f = read_page_format(tif);
  if (!(f == s.format)) {
    fail_input(path, "page " + std::to_string(page) + " is " + format_text(f) + " but page 0 is " +
                         format_text(s.format) + "; all pages must match");
  }
}

}  // namespace

// Where each page's directory starts, from one walk of the chain that checked every
// page's format.
class TiffPageIndex {
 public:
  CheckedStack stack;
  std::vector<std::uint64_t> offsets;  // of page p's IFD

  // A handle of the file for one read: an idle one (libtiff keeps what it learnt of
  // the directory chain in it: opening the file anew walked the whole chain on every
  // read), else a new one. Given back by `give_back` after a read that succeeded.
  [[nodiscard]] std::unique_ptr<TiffHandle> take(const fs::path& path) const {
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      if (!idle_.empty()) {
        std::unique_ptr<TiffHandle> h = std::move(idle_.back());
        idle_.pop_back();
        h->activate();  // this thread's sink for the read (TiffHandle)
        return h;
      }
    }
    return open_for_read(path);
  }
  void give_back(std::unique_ptr<TiffHandle> handle) const {
    handle->deactivate();  // on the thread that read with it
    const std::lock_guard<std::mutex> lock(mutex_);
    if (idle_.size() < kMaxIdle) idle_.push_back(std::move(handle));
  }

 private:
  static constexpr std::size_t kMaxIdle = 64;  // one per thread reading at once
  mutable std::mutex mutex_;
  mutable std::vector<std::unique_ptr<TiffHandle>> idle_;
};

namespace {

// The page loop of read_tiff_stack and read_tiff_region: fills `shape`'s header
// (nz = z_end - z_begin; z_end -1: the last page), calls `allocate` once the file has
// been checked (before any page is decoded), then decodes the strips or tiles of
// each page of [z_begin, z_end) that meet `window` into sink.target(z) and hands the
// page to sink.done. Without `index` it walks the directory chain from page 0; with
// it, it goes to each page's directory by its offset.
void read_pages(const fs::path& path, const TiffReadOptions& options, int z_begin, int z_end, const PageWindow& window,
                Volume& shape, const std::function<void(Volume&)>& allocate, const PageSink& sink,
                const TiffPageIndex* index = nullptr) {
  std::unique_ptr<TiffHandle> handle = index ? index->take(path) : open_for_read(path);
  TIFF* tif = handle->get();
  const CheckedStack checked = index ? index->stack : check_stack(tif, *handle, path, options);
  const StackLayout& s = checked.s;
  if (z_end < 0) z_end = s.nz;
  if (z_begin < 0 || z_end > s.nz || z_begin >= z_end) {
    throw std::invalid_argument("read_tiff_region: pages [" + std::to_string(z_begin) + ", " + std::to_string(z_end) +
                                ") are not inside the stack's " + std::to_string(s.nz));
  }
  const int slab = z_end - z_begin;
  const int channel = options.channel.value_or(0);
  const int page_channel = channel / s.format.samples;
  const int sample = channel % s.format.samples;
  const int nx = static_cast<int>(s.format.width), ny = static_cast<int>(s.format.height);
  // z (within the slab) of each page we need (-1: another channel, or outside the slab).
  std::vector<int> z_of_page(static_cast<std::size_t>(s.pages), -1);
  int last_page = 0;
  for (int z = z_begin; z < z_end; ++z) {
    const int page = z * s.stride_z + page_channel * s.stride_c;
    z_of_page[static_cast<std::size_t>(page)] = z - z_begin;
    last_page = std::max(last_page, page);
  }

  Volume& volume = shape;
  volume.nx = nx;
  volume.ny = ny;
  volume.nz = slab;
  volume.stored_as = s.type;
  volume.spacing = s.spacing;
  volume.normalization = Normalization{};
  volume.source = path.string();
  allocate(volume);

  DecodeBuffer buffer;
  const std::size_t page_voxels = static_cast<std::size_t>(nx) * ny;
  for (int page = index ? z_begin * s.stride_z + page_channel * s.stride_c : 0; page <= last_page; ++page) {
    const int z = z_of_page[static_cast<std::size_t>(page)];
    if (index) {
      if (z < 0) continue;
      if (!TIFFSetSubDirectory(tif, index->offsets[static_cast<std::size_t>(page)]) || handle->messages().errors > 0) {
        fail_input(path, "cannot read page " + std::to_string(page) + " of " + std::to_string(s.pages) +
                             handle->detail());
      }
    } else if (page > 0) {
      next_page(tif, *handle, path, page, s);
    }
    if (z < 0) continue;
    if (page > 0 || index) check_page_data(tif, path, page, s, checked.file_size);  // page 0: checked before allocating
    float* dst = sink.target(z);
    decode_page(tif, *handle, path, page, s, sample, dst, buffer, window);
    if (handle->messages().errors > 0) {
      fail_input(path, "cannot decode page " + std::to_string(page) + handle->detail());
    }
    if (s.type == SampleType::kFloat32) {
      const float* bad = std::find_if(dst, dst + page_voxels, [](float v) { return !std::isfinite(v); });
      if (bad != dst + page_voxels) {
        const auto i = static_cast<std::size_t>(bad - dst);
        fail_input(path, "voxel (x=" + std::to_string(i % nx) + ", y=" + std::to_string(i / nx) + ", z=" +
                             std::to_string(z + z_begin) + ") is " + non_finite_text(*bad) + "; float stacks must be finite");
      }
    }
    if (sink.done) sink.done(z, dst);
  }
  if (index && handle->messages().errors == 0) index->give_back(std::move(handle));  // a failed read's is closed
}

}  // namespace

Volume read_tiff_stack(const fs::path& path, const TiffReadOptions& options) {
  Volume volume;
  read_pages(
      path, options, 0, -1, PageWindow{}, volume,
      [&](Volume& v) {
        check_allocation(path, 4.0 * v.nx * v.ny * static_cast<double>(v.nz),
                         std::to_string(v.nx) + "x" + std::to_string(v.ny) + "x" + std::to_string(v.nz) +
                             " float32 voxels");
        v.voxels.resize(v.size());
      },
      PageSink{[&](int z) { return volume.voxels.data() + static_cast<std::size_t>(z) * volume.nx * volume.ny; }, {}});
  return volume;
}

std::shared_ptr<const TiffPageIndex> index_tiff_pages(const fs::path& path, const TiffReadOptions& options) {
  const std::unique_ptr<TiffHandle> handle = open_for_read(path);
  TIFF* tif = handle->get();
  auto index = std::make_shared<TiffPageIndex>();
  index->stack = check_stack(tif, *handle, path, options);
  const StackLayout& s = index->stack.s;
  index->offsets.reserve(static_cast<std::size_t>(s.pages));
  for (int page = 0; page < s.pages; ++page) {
    if (page > 0) next_page(tif, *handle, path, page, s);
    index->offsets.push_back(TIFFCurrentDirOffset(tif));
  }
  return index;
}

void read_tiff_region(const fs::path& path, const TiffReadOptions& options, const std::array<int, 3>& lo,
                      const std::array<int, 3>& hi, float* out, const TiffPageIndex* index) {
  if (lo[0] < 0 || lo[1] < 0 || lo[0] >= hi[0] || lo[1] >= hi[1]) {
    throw std::invalid_argument("read_tiff_region: the box is empty or outside the stack");
  }
  Volume shape;
  std::vector<float> scratch;
  const PageWindow window{static_cast<std::uint32_t>(lo[0]), static_cast<std::uint32_t>(hi[0]),
                          static_cast<std::uint32_t>(lo[1]), static_cast<std::uint32_t>(hi[1])};
  read_pages(
      path, options, lo[2], hi[2], window, shape,
      [&](Volume& v) {
        if (hi[0] > v.nx || hi[1] > v.ny) throw std::invalid_argument("read_tiff_region: the box is outside the stack");
        scratch.resize(static_cast<std::size_t>(v.nx) * v.ny);
      },
      PageSink{[&](int) { return scratch.data(); },
               [&](int z, const float* page) {
                 const std::size_t w = static_cast<std::size_t>(hi[0] - lo[0]);
                 float* dst = out + static_cast<std::size_t>(z) * w * static_cast<std::size_t>(hi[1] - lo[1]);
                 for (int y = lo[1]; y < hi[1]; ++y) {
                   const float* row = page + static_cast<std::size_t>(y) * shape.nx + lo[0];
                   dst = std::copy(row, row + w, dst);
                 }
               }},
      index);
}

}  // namespace hisnegs::io
