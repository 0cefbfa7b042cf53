// SPDX-License-Identifier: Apache-2.0
// The allocation limit for untrusted sizes: HISNEGS_MAX_ALLOC_GB or MemAvailable.
#include "io/memory_limit.hpp"

#include <unistd.h>

#include <cctype>
#include <cmath>
#include <utility>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <limits>

#include "io/detail/tiff_metadata.hpp"
#include "io/error.hpp"

namespace hisnegs::io {

namespace {
constexpr double kGiBytes = 1024.0 * 1024.0 * 1024.0;
}  // namespace

double allocation_limit_bytes(std::string* source) {
  std::string ignored;
  std::string& what = source ? *source : ignored;
  if (const char* env = std::getenv("HISNEGS_MAX_ALLOC_GB"); env && *env) {
    const std::optional<double> gib = detail::parse_double(env);
    if (!gib || !std::isfinite(*gib) || *gib <= 0) {
      throw InputError(std::string("HISNEGS_MAX_ALLOC_GB=") + printable(env, 40) + " is not a positive number of GiB");
    }
    what = "HISNEGS_MAX_ALLOC_GB";
    return *gib * kGiBytes;
  }
  std::ifstream meminfo("/proc/meminfo");
  std::string key;
  double kb = 0;
  std::string unit;
  while (meminfo >> key >> kb >> unit) {
    if (key == "MemAvailable:") {
      what = "MemAvailable; set HISNEGS_MAX_ALLOC_GB to change it";
      return kb * 1024.0;
    }
  }
  what = "unknown";
  return std::numeric_limits<double>::infinity();
}

std::optional<double> parse_memory_size(std::string_view text, std::string_view field) {
  if (text == "auto") return std::nullopt;
  const auto fail = [&](const std::string& why) -> std::optional<double> {
    throw InputError(std::string(field) + " = '" + printable(std::string(text), 40) + "': " + why);
  };
  std::size_t end = 0;
  while (end < text.size() && (std::isdigit(static_cast<unsigned char>(text[end])) || text[end] == '.')) ++end;
  const std::optional<double> number = detail::parse_double(std::string(text.substr(0, end)));
  if (end == 0 || !number || !std::isfinite(*number)) {
    return fail("expected auto or a size such as 1GiB, 512MiB, 2GB");
  }
  std::string unit(text.substr(end));
  unit.erase(0, unit.find_first_not_of(' '));
  static const std::pair<const char*, double> kUnits[] = {
      {"", 1.0},           {"B", 1.0},           {"K", 1024.0},        {"KiB", 1024.0},      {"KB", 1e3},
      {"M", 1048576.0},    {"MiB", 1048576.0},   {"MB", 1e6},          {"G", kGiBytes},      {"GiB", kGiBytes},
      {"GB", 1e9},         {"T", kGiBytes * 1024}, {"TiB", kGiBytes * 1024}, {"TB", 1e12}};
  for (const auto& [name, factor] : kUnits) {
    if (unit == name) {
      const double bytes = *number * factor;
      if (!(bytes >= 1.0)) return fail("must be at least 1 byte");
      return bytes;
    }
  }
  return fail("unknown unit '" + printable(unit, 16) + "' (B, KiB, MiB, GiB, TiB, KB, MB, GB, TB)");
}

double physical_memory_bytes() {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  return pages > 0 && page > 0 ? static_cast<double>(pages) * static_cast<double>(page) : 0.0;
}

MemoryLimit resolve_memory_limit(std::string_view text, std::string_view field) {
  if (const std::optional<double> bytes = parse_memory_size(text, field)) {
    return {*bytes, std::string(field) + " " + gib_text(*bytes)};
  }
  const double ram = physical_memory_bytes();
  if (ram > 0) return {0.5 * ram, "auto: half of " + gib_text(ram) + " of RAM"};
  return {8.0 * kGiBytes, "auto: 8 GiB (RAM unknown)"};
}

std::string gib_text(double bytes) {
  char text[64];
  std::snprintf(text, sizeof text, "%.2f GiB", bytes / kGiBytes);
  return text;
}

void check_allocation(const std::filesystem::path& path, double bytes, const std::string& what) {
  std::string limit_source;
  const double limit = allocation_limit_bytes(&limit_source);
  if (bytes > limit) {
    fail_input(path, "would need " + gib_text(bytes) + " for " + what + " but the limit is " + gib_text(limit) + " (" +
                         limit_source + ")");
  }
}

}  // namespace hisnegs::io
