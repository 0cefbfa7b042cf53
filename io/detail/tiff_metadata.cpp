// SPDX-License-Identifier: Apache-2.0
// ImageJ description and OME-XML <Pixels> parsing, length units, and the spacing
// precedence. Pure string work: reading tags from a TIFF is tiff_stack.cpp's job.
#include "io/detail/tiff_metadata.hpp"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "io/error.hpp"

namespace hisnegs::io::detail {
namespace {

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\n' || c == '\r' || c == '\f' || c == '\v'; }

std::string_view trim(std::string_view s) {
  while (!s.empty() && is_space(s.front())) s.remove_prefix(1);
  while (!s.empty() && is_space(s.back())) s.remove_suffix(1);
  return s;
}

std::string ascii_lower(std::string_view s) {
  std::string out(s);
  for (char& c : out) {
    if (c >= 'A' && c <= 'Z') c = static_cast<char>(c - 'A' + 'a');
  }
  return out;
}

// Keeps error messages single-line and short even for hostile metadata.
std::string printable(std::string_view s) { return io::printable(s, 40); }

// Appends the UTF-8 encoding of `cp` (used for XML character references).
void append_utf8(std::string& out, std::uint32_t cp) {
  if (cp < 0x80) {
    out += static_cast<char>(cp);
  } else if (cp < 0x800) {
    out += static_cast<char>(0xC0 | (cp >> 6));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  } else if (cp < 0x10000) {
    out += static_cast<char>(0xE0 | (cp >> 12));
    out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  } else {
    out += static_cast<char>(0xF0 | (cp >> 18));
    out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
    out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  }
}

// Decodes the five predefined XML entities and numeric character references.
// Unknown or unterminated references are kept as written.
std::string decode_xml_entities(std::string_view s) {
  std::string out;
  out.reserve(s.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] != '&') {
      out += s[i];
      continue;
    }
    const std::size_t semi = s.find(';', i);
    if (semi == std::string_view::npos || semi - i > 12) {
      out += s[i];
      continue;
    }
    const std::string_view ent = s.substr(i + 1, semi - i - 1);
    bool ok = true;
    if (ent == "amp")
      out += '&';
    else if (ent == "lt")
      out += '<';
    else if (ent == "gt")
      out += '>';
    else if (ent == "quot")
      out += '"';
    else if (ent == "apos")
      out += '\'';
    else if (ent.size() > 1 && ent[0] == '#') {
      const bool hex = ent[1] == 'x' || ent[1] == 'X';
      const std::string_view digits = ent.substr(hex ? 2 : 1);
      std::uint32_t cp = 0;
      const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), cp, hex ? 16 : 10);
      ok = ec == std::errc() && ptr == digits.data() + digits.size() && !digits.empty() && cp <= 0x10FFFF;
      if (ok) append_utf8(out, cp);
    } else {
      ok = false;
    }
    if (ok) {
      i = semi;
    } else {
      out += s[i];
    }
  }
  return out;
}

[[noreturn]] void fail(const std::string& message) { throw InputError(message); }

}  // namespace

std::optional<double> parse_double(std::string_view text) {
  text = trim(text);
  if (!text.empty() && text.front() == '+') text.remove_prefix(1);
  if (text.empty()) return std::nullopt;
  double value = 0;
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || ptr != text.data() + text.size()) return std::nullopt;
  return value;
}

std::optional<long long> parse_integer(std::string_view text) {
  text = trim(text);
  if (!text.empty() && text.front() == '+') text.remove_prefix(1);
  if (text.empty()) return std::nullopt;
  long long value = 0;
  const auto [ptr, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || ptr != text.data() + text.size()) return std::nullopt;
  return value;
}

bool is_pixel_unit(std::string_view unit) {
  const std::string u = ascii_lower(trim(unit));
  return u.empty() || u == "pixel" || u == "pixels" || u == "px" || u == "reference frame";
}

std::optional<double> length_unit_um(std::string_view unit) {
  unit = trim(unit);
  // Symbols are case-sensitive (mm is not Mm); OME UnitsLength spellings first.
  static const std::pair<std::string_view, double> kSymbols[] = {
      {"\xC2\xB5m", 1.0},  // µm, U+00B5 MICRO SIGN in UTF-8 (OME's spelling)
      {"\xCE\xBCm", 1.0},  // μm, U+03BC GREEK SMALL LETTER MU
      {"\xB5m", 1.0},      // µm in Latin-1 (old ImageJ files)
      {"\\u00B5m", 1.0},   // ImageJ escapes µ in its description this way
      {"\\u00b5m", 1.0},
      {"um", 1.0},
      {"nm", 1e-3},
      {"pm", 1e-6},
      {"mm", 1e3},
      {"cm", 1e4},
      {"dm", 1e5},
      {"m", 1e6},
      {"\xC3\x85", 1e-4},      // Å, U+00C5
      {"\xE2\x84\xAB", 1e-4},  // Å, U+212B ANGSTROM SIGN
      {"\xC5", 1e-4},          // Å in Latin-1
      {"in", 25400.0},
  };
  for (const auto& [symbol, um] : kSymbols) {
    if (unit == symbol) return um;
  }
  static const std::pair<std::string_view, double> kWords[] = {
      {"micron", 1.0},      {"microns", 1.0},     {"micrometer", 1.0},  {"micrometers", 1.0}, {"micrometre", 1.0},
      {"micrometres", 1.0}, {"nanometer", 1e-3},  {"nanometers", 1e-3}, {"nanometre", 1e-3},  {"nanometres", 1e-3},
      {"millimeter", 1e3},  {"millimeters", 1e3}, {"millimetre", 1e3},  {"millimetres", 1e3}, {"centimeter", 1e4},
      {"centimeters", 1e4}, {"centimetre", 1e4},  {"centimetres", 1e4}, {"meter", 1e6},       {"meters", 1e6},
      {"metre", 1e6},       {"metres", 1e6},      {"inch", 25400.0},    {"inches", 25400.0},  {"angstrom", 1e-4},
      {"angstroms", 1e-4},
  };
  const std::string lower = ascii_lower(unit);
  for (const auto& [word, um] : kWords) {
    if (lower == word) return um;
  }
  return std::nullopt;
}

bool is_imagej_description(std::string_view text) { return trim(text).starts_with("ImageJ="); }

ImageJDescription parse_imagej_description(std::string_view text) {
  ImageJDescription d;
  std::optional<std::string> spacing_text;
  std::size_t pos = 0;
  while (pos < text.size()) {
    std::size_t end = text.find('\n', pos);
    if (end == std::string_view::npos) end = text.size();
    const std::string_view line = trim(text.substr(pos, end - pos));
    pos = end + 1;
    const std::size_t eq = line.find('=');
    if (eq == std::string_view::npos) continue;
    const std::string_view key = trim(line.substr(0, eq));
    const std::string_view value = trim(line.substr(eq + 1));
    auto count = [&](std::optional<int>& field) {
      const std::optional<long long> n = parse_integer(value);
      if (!n || *n < 1 || *n > std::numeric_limits<int>::max()) {
        fail("ImageJ description: " + std::string(key) + "=" + printable(value) + " is not a positive integer");
      }
      field = static_cast<int>(*n);
    };
    if (key == "images")
      count(d.images);
    else if (key == "channels")
      count(d.channels);
    else if (key == "slices")
      count(d.slices);
    else if (key == "frames")
      count(d.frames);
    else if (key == "hyperstack")
      d.hyperstack = value == "true";
    else if (key == "unit")
      d.unit = std::string(value);
    else if (key == "spacing")
      spacing_text = std::string(value);
  }
  if (!is_pixel_unit(d.unit)) {
    d.um_per_unit = length_unit_um(d.unit);
    if (!d.um_per_unit) {
      d.spacing_error = "ImageJ description: unit=" + printable(d.unit) +
                        " is not a known length unit (expected um, micron, nm, mm, cm, ...)";
    }
  }
  if (spacing_text) {
    d.spacing = parse_double(*spacing_text);
    if (!d.spacing) {
      d.spacing_error = "ImageJ description: spacing=" + printable(*spacing_text) + " is not a number";
    } else if (!std::isfinite(*d.spacing) || *d.spacing <= 0) {
      d.spacing_error = "ImageJ description: spacing=" + printable(*spacing_text) + " must be a positive finite number";
      d.spacing.reset();
    }
  }
  return d;
}

bool is_ome_xml(std::string_view text) {
  // The root element may carry a namespace prefix (<ome:OME ...>).
  for (std::size_t p = text.find("OME"); p != std::string_view::npos; p = text.find("OME", p + 1)) {
    const std::size_t after = p + 3;
    const bool ends = after == text.size() || is_space(text[after]) || text[after] == '>';
    if (!ends || p == 0) continue;
    if (text[p - 1] == '<' || text[p - 1] == ':') return true;
  }
  return false;
}

namespace {

using XmlAttributes = std::vector<std::pair<std::string, std::string>>;

// Where the attributes of the first start tag whose local name is "Pixels" begin.
std::size_t find_pixels_tag(std::string_view xml) {
  for (std::size_t i = xml.find('<'); i != std::string_view::npos; i = xml.find('<', i + 1)) {
    if (xml.substr(i, 4) == "<!--") {
      const std::size_t close = xml.find("-->", i + 4);
      if (close == std::string_view::npos) break;
      i = close + 2;
      continue;
    }
    std::size_t j = i + 1;
    while (j < xml.size() && !is_space(xml[j]) && xml[j] != '>' && xml[j] != '/') ++j;
    std::string_view name = xml.substr(i + 1, j - i - 1);
    if (const std::size_t colon = name.rfind(':'); colon != std::string_view::npos) {
      name.remove_prefix(colon + 1);
    }
    if (name == "Pixels") return j;
  }
  fail("OME-XML: no <Pixels> element");
}

// The attributes of the tag whose attribute list starts at `k` (entities decoded).
XmlAttributes parse_tag_attributes(std::string_view xml, std::size_t k) {
  XmlAttributes attrs;
  for (;;) {
    while (k < xml.size() && is_space(xml[k])) ++k;
    if (k >= xml.size()) fail("OME-XML: unterminated <Pixels> element");
    if (xml[k] == '>' || xml[k] == '/') break;
    const std::size_t name_begin = k;
    while (k < xml.size() && !is_space(xml[k]) && xml[k] != '=' && xml[k] != '>') ++k;
    const std::string name(xml.substr(name_begin, k - name_begin));
    while (k < xml.size() && is_space(xml[k])) ++k;
    if (k >= xml.size() || xml[k] != '=') fail("OME-XML: malformed attribute " + printable(name) + " in <Pixels>");
    ++k;
    while (k < xml.size() && is_space(xml[k])) ++k;
    if (k >= xml.size() || (xml[k] != '"' && xml[k] != '\'')) {
      fail("OME-XML: attribute " + printable(name) + " in <Pixels> is not quoted");
    }
    const char quote = xml[k++];
    const std::size_t close = xml.find(quote, k);
    if (close == std::string_view::npos) fail("OME-XML: unterminated attribute " + printable(name) + " in <Pixels>");
    attrs.emplace_back(name, decode_xml_entities(xml.substr(k, close - k)));
    k = close + 1;
  }
  return attrs;
}

const std::string* find_attribute(const XmlAttributes& attrs, std::string_view name) {
  for (const auto& [n, v] : attrs) {
    if (n == name) return &v;
  }
  return nullptr;
}

// SizeX..SizeT (X and Y required) and DimensionOrder.
void read_pixel_sizes(const XmlAttributes& attrs, OmePixels& px) {
  auto size = [&](std::string_view name, int& field, bool required) {
    const std::string* v = find_attribute(attrs, name);
    if (!v) {
      if (required) fail("OME-XML: <Pixels> has no " + std::string(name) + " attribute");
      return;
    }
    const std::optional<long long> n = parse_integer(*v);
    if (!n || *n < 1 || *n > std::numeric_limits<int>::max()) {
      fail("OME-XML: " + std::string(name) + "=\"" + printable(*v) + "\" is not a positive integer");
    }
    field = static_cast<int>(*n);
  };
  size("SizeX", px.size_x, true);
  size("SizeY", px.size_y, true);
  size("SizeZ", px.size_z, false);
  size("SizeC", px.size_c, false);
  size("SizeT", px.size_time, false);

  // The schema requires DimensionOrder; without it XYZCT (the common order) is assumed.
  px.dimension_order = "XYZCT";
  if (const std::string* order = find_attribute(attrs, "DimensionOrder")) {
    std::string sorted = *order;
    if (sorted.size() == 5) std::sort(sorted.begin() + 2, sorted.end());
    if (sorted != "XYCTZ" || !order->starts_with("XY")) {
      fail("OME-XML: DimensionOrder=\"" + printable(*order) + "\" is not XY followed by Z, C, T in some order");
    }
    px.dimension_order = *order;
  }
}

// PhysicalSize{X,Y,Z} in µm; a bad value or unit is kept as px.spacing_error (thrown
// only if the spacing is used), a pixel unit means "not calibrated".
void read_physical_sizes(const XmlAttributes& attrs, OmePixels& px) {
  static const char* const kAxis[3] = {"X", "Y", "Z"};
  for (int a = 0; a < 3; ++a) {
    const std::string attr = std::string("PhysicalSize") + kAxis[a];
    const std::string* value = find_attribute(attrs, attr);
    if (!value) continue;
    const std::string* unit_attr = find_attribute(attrs, attr + "Unit");
    const std::string unit = unit_attr ? *unit_attr : std::string("\xC2\xB5m");
    std::string problem;
    const std::optional<double> v = parse_double(*value);
    const std::optional<double> um_per_unit = length_unit_um(unit);
    if (!v) {
      problem = "OME-XML: " + attr + "=\"" + printable(*value) + "\" is not a number";
    } else if (!std::isfinite(*v) || *v <= 0) {
      problem = "OME-XML: " + attr + "=\"" + printable(*value) + "\" must be a positive finite number";
    } else if (is_pixel_unit(unit)) {
      continue;  // calibrated in pixels: no physical size
    } else if (!um_per_unit) {
      problem = "OME-XML: " + attr + "Unit=\"" + printable(unit) +
                "\" is not a known length unit (expected \xC2\xB5m, nm, mm, cm, ...)";
    }
    if (!problem.empty()) {
      if (px.spacing_error.empty()) px.spacing_error = problem;
      continue;
    }
    px.physical_size_um[a] = *v * *um_per_unit;
  }
}

}  // namespace

OmePixels parse_ome_pixels(std::string_view xml) {
  const XmlAttributes attrs = parse_tag_attributes(xml, find_pixels_tag(xml));
  OmePixels px;
  read_pixel_sizes(attrs, px);
  read_physical_sizes(attrs, px);
  return px;
}

VoxelSpacing resolve_spacing(const SpacingEvidence& evidence) {
  VoxelSpacing s;
  if (evidence.user_um) {
    s.um = *evidence.user_um;
    s.source = {SpacingSource::kUser, SpacingSource::kUser, SpacingSource::kUser};
    return s;
  }
  if (evidence.ome && !evidence.ome->spacing_error.empty()) throw InputError(evidence.ome->spacing_error);
  if (evidence.imagej && !evidence.imagej->spacing_error.empty()) throw InputError(evidence.imagej->spacing_error);

  const double resolution[2] = {evidence.x_resolution, evidence.y_resolution};
  auto usable = [](double r) { return std::isfinite(r) && r > 0; };
  for (int a = 0; a < 3; ++a) {
    if (evidence.ome && evidence.ome->physical_size_um[a]) {
      s.um[a] = *evidence.ome->physical_size_um[a];
      s.source[a] = SpacingSource::kOmeXml;
      continue;
    }
    const std::optional<double> ij_unit = evidence.imagej ? evidence.imagej->um_per_unit : std::nullopt;
    if (a < 2) {
      if (ij_unit && usable(resolution[a])) {
        s.um[a] = *ij_unit / resolution[a];  // resolution is pixels per unit
        s.source[a] = SpacingSource::kImageJResolution;
      } else if (evidence.resolution_unit == 3 && usable(resolution[a])) {
        s.um[a] = 1e4 / resolution[a];  // pixels per centimetre
        s.source[a] = SpacingSource::kTiffResolution;
      }
    } else if (ij_unit && evidence.imagej->spacing) {
      s.um[a] = *evidence.imagej->spacing * *ij_unit;
      s.source[a] = SpacingSource::kImageJSpacing;
    }
    if (!std::isfinite(s.um[a]) || s.um[a] <= 0) {
      // 1/resolution can only overflow for denormal resolutions; treat as absent.
      s.um[a] = 1.0;
      s.source[a] = SpacingSource::kDefault;
    }
    if (const std::string problem = voxel_size_problem(s.um[a]); !problem.empty()) {
      static const char* const kAxis[3] = {"x", "y", "z"};
      throw InputError(std::string("voxel size ") + kAxis[a] + " = " + number_text(s.um[a]) + " um from " +
                       std::string(to_string(s.source[a])) + " " + problem);
    }
  }
  return s;
}

}  // namespace hisnegs::io::detail
