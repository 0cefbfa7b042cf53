// SPDX-License-Identifier: Apache-2.0
// The allocation limit for untrusted sizes: HISNEGS_MAX_ALLOC_GB or MemAvailable.
#include "io/memory_limit.hpp"

#include <cmath>
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
