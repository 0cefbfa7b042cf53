// SPDX-License-Identifier: Apache-2.0
// Pure parsing of TIFF ImageDescription metadata (ImageJ keys, OME-XML <Pixels>) and the spacing precedence.
// No libtiff and no file access: tiff_stack.cpp reads the tags and hands their text and values to these functions.
#pragma once

#include <array>
#include <optional>
#include <string>
#include <string_view>

#include "io/volume.hpp"

namespace hisnegs::io::detail {

// Micrometres per `unit` for a length unit as written by ImageJ or OME
// ("um", "µm" in UTF-8, Latin-1 0xB5 'm', ImageJ's literal "\u00B5m", "micron",
// "nm", "mm", "cm", "m", "pm", "Å", "in"/"inch"). nullopt when unknown.
[[nodiscard]] std::optional<double> length_unit_um(std::string_view unit);

// True when `unit` means "not calibrated" ("", "pixel", "pixels", "px",
// OME's "reference frame").
[[nodiscard]] bool is_pixel_unit(std::string_view unit);

// Parses a whole (whitespace-trimmed) decimal number; nullopt if anything is left
// over or it is not a number. Infinity/NaN spellings are returned as such.
[[nodiscard]] std::optional<double> parse_double(std::string_view text);
[[nodiscard]] std::optional<long long> parse_integer(std::string_view text);

// The keys of an ImageJ ImageDescription ("ImageJ=1.x\nimages=..\n...") that
// hisnegs uses. Counts are absent when the key is missing.
struct ImageJDescription {
  std::optional<int> images;          // total pages = channels * slices * frames
  std::optional<int> channels;        // hyperstack channels (pages interleaved, C fastest)
  std::optional<int> slices;          // Z
  std::optional<int> frames;          // T
  bool hyperstack = false;            // `hyperstack=true`
  std::string unit;                   // `unit=` as written ("" if missing)
  std::optional<double> um_per_unit;  // µm per `unit`; nullopt if unknown or pixel
  std::optional<double> spacing;      // `spacing=` (z step) in `unit`
  // Why the calibration cannot be used (an unknown unit, `spacing=abc`, a
  // non-positive spacing); empty when fine. Reported only when the spacing is
  // needed, so --spacing can override a broken calibration.
  std::string spacing_error;
};

// True when `text` starts with "ImageJ=" (leading whitespace allowed).
[[nodiscard]] bool is_imagej_description(std::string_view text);

// Parses the ImageJ keys above; unknown keys are ignored (ImageJ writes many).
// Throws InputError("ImageJ description: channels=x is not a positive integer")
// for malformed or non-positive counts. The message has no path: callers prefix it.
[[nodiscard]] ImageJDescription parse_imagej_description(std::string_view text);

// The attributes of the first OME-XML <Pixels> element that hisnegs uses.
struct OmePixels {
  std::string dimension_order;                                        // "XY" + a permutation of "ZCT", e.g. "XYZCT"
  int size_x = 0, size_y = 0, size_z = 1, size_c = 1, size_time = 1;  // SizeX..SizeT
  std::array<std::optional<double>, 3> physical_size_um;              // x, y, z; nullopt if absent/pixel
  std::string spacing_error;  // as ImageJDescription::spacing_error (names the attribute)
};

// True when `text` holds an OME-XML document (an <OME root element).
[[nodiscard]] bool is_ome_xml(std::string_view text);

// Parses the first <Pixels ...> start tag (any namespace prefix, attributes in any
// order, single or double quotes, XML entities decoded). PhysicalSize?Unit
// defaults to µm. Throws InputError naming the attribute for a missing or
// malformed DimensionOrder or Size?, or when no <Pixels> element exists.
[[nodiscard]] OmePixels parse_ome_pixels(std::string_view xml);

// Everything the spacing precedence looks at, per CONVENTIONS "Volume".
struct SpacingEvidence {
  std::optional<std::array<double, 3>> user_um;  // --spacing / config (wins)
  const OmePixels* ome = nullptr;                // OME-XML, if the file has it
  const ImageJDescription* imagej = nullptr;     // ImageJ description, if any
  double x_resolution = 0;                       // TIFF XResolution in pixels per unit; <= 0 when absent
  double y_resolution = 0;                       // TIFF YResolution
  int resolution_unit = 2;                       // TIFF ResolutionUnit: 1 none, 2 inch (the default), 3 cm
};

// Resolves spacing axis by axis: user > OME PhysicalSize > ImageJ (x, y from
// X/YResolution in the description's unit; z from spacing=) > X/YResolution
// with ResolutionUnit = centimeter > 1 µm default. ResolutionUnit inch without
// an ImageJ unit is display DPI (72, 300, ...) written by most image software,
// not a physical calibration, so it is ignored. Throws InputError with the
// metadata's spacing_error when the stored calibration is broken and needed.
[[nodiscard]] VoxelSpacing resolve_spacing(const SpacingEvidence& evidence);

}  // namespace hisnegs::io::detail
