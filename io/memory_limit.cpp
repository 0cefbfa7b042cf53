// SPDX-License-Identifier: Apache-2.0
// The allocation limit for untrusted sizes: HISNEGS_MAX_ALLOC_GB, or MemAvailable
// and the cgroup's headroom (a Slurm job's --mem, a container's limit).
#include "io/memory_limit.hpp"

#include <unistd.h>

#include <algorithm>
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

// One number from a cgroup file: nullopt for "max", a missing file or a value of
// 2^60 or more (cgroup v1 writes "no limit" as 2^63 rounded down to a page).
std::optional<double> cgroup_number(const std::filesystem::path& file) {
  std::ifstream in(file);
  std::string text;
  if (!(in >> text) || text == "max") return std::nullopt;
  const std::optional<double> value = detail::parse_double(text);
  if (!value || !(*value >= 0) || *value >= 1152921504606846976.0) return std::nullopt;
  return value;
}

// This process' memory cgroup directory and the mount it lies under, from
// /proc/self/cgroup: v2's "0::PATH" under /sys/fs/cgroup, or v1's "N:memory:PATH"
// under /sys/fs/cgroup/memory. Inside a container the path may name the host's
// hierarchy, which the container sees as its mount's root: then the root is used.
struct CgroupPlace {
  std::filesystem::path mount, dir;
  bool v2 = false;
};
std::optional<CgroupPlace> memory_cgroup(const std::filesystem::path& proc_self_cgroup,
                                         const std::filesystem::path& sys_fs_cgroup) {
  std::ifstream in(proc_self_cgroup);
  std::string line;
  std::optional<CgroupPlace> v1, v2;
  while (std::getline(in, line)) {
    const std::size_t a = line.find(':'), b = a == std::string::npos ? a : line.find(':', a + 1);
    if (b == std::string::npos) continue;
    const std::string controllers = line.substr(a + 1, b - a - 1), path = line.substr(b + 1);
    const bool memory_v1 = ("," + controllers + ",").find(",memory,") != std::string::npos;
    if (!(controllers.empty() && line.compare(0, 2, "0:") == 0) && !memory_v1) continue;
    CgroupPlace place{memory_v1 ? sys_fs_cgroup / "memory" : sys_fs_cgroup, {}, !memory_v1};
    std::error_code ec;
    place.dir = place.mount / std::filesystem::path(path).relative_path();
    if (!std::filesystem::is_directory(place.dir, ec)) place.dir = place.mount;
    (memory_v1 ? v1 : v2) = place;
  }
  if (v1 && std::filesystem::exists(v1->mount / "memory.limit_in_bytes")) return v1;
  if (v2 && std::filesystem::exists(v2->mount / "cgroup.controllers")) return v2;
  return std::nullopt;
}

}  // namespace

std::optional<CgroupMemory> cgroup_memory(const std::filesystem::path& proc_self_cgroup,
                                          const std::filesystem::path& sys_fs_cgroup) {
  const std::optional<CgroupPlace> place = memory_cgroup(proc_self_cgroup, sys_fs_cgroup);
  if (!place) return std::nullopt;
  const char* limit_file = place->v2 ? "memory.max" : "memory.limit_in_bytes";
  const char* usage_file = place->v2 ? "memory.current" : "memory.usage_in_bytes";
  std::optional<CgroupMemory> tightest;
  for (std::filesystem::path dir = place->dir;; dir = dir.parent_path()) {
    if (const std::optional<double> limit = cgroup_number(dir / limit_file)) {
      const double headroom = std::max(0.0, *limit - cgroup_number(dir / usage_file).value_or(0.0));
      if (!tightest || headroom < tightest->headroom) tightest = CgroupMemory{*limit, headroom};
    }
    if (dir == place->mount || !dir.has_relative_path()) break;
  }
  return tightest;
}

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
  double limit = std::numeric_limits<double>::infinity();
  what = "unknown";
  std::ifstream meminfo("/proc/meminfo");
  std::string key;
  double kb = 0;
  std::string unit;
  while (meminfo >> key >> kb >> unit) {
    if (key == "MemAvailable:") {
      limit = kb * 1024.0;
      what = "MemAvailable; set HISNEGS_MAX_ALLOC_GB to change it";
      break;
    }
  }
  // MemAvailable counts the whole machine; a job or container may have less.
  if (const std::optional<CgroupMemory> cgroup = cgroup_memory(); cgroup && cgroup->headroom < limit) {
    limit = cgroup->headroom;
    what = "the memory cgroup's limit less its use; set HISNEGS_MAX_ALLOC_GB to change it";
  }
  return limit;
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

double usable_memory_bytes(std::string* source) {
  double bytes = physical_memory_bytes();
  std::string what = "RAM";
  if (const std::optional<CgroupMemory> cgroup = cgroup_memory();
      cgroup && (bytes <= 0 || cgroup->limit < bytes)) {
    bytes = cgroup->limit;
    what = "memory cgroup limit";
  }
  if (source) *source = what;
  return bytes;
}

MemoryLimit resolve_memory_limit(std::string_view text, std::string_view field) {
  if (const std::optional<double> bytes = parse_memory_size(text, field)) {
    return {*bytes, std::string(field) + " " + gib_text(*bytes)};
  }
  std::string what;
  const double ram = usable_memory_bytes(&what);
  if (ram > 0) return {0.5 * ram, "auto: half of " + gib_text(ram) + " of " + what};
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
