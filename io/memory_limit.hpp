// SPDX-License-Identifier: Apache-2.0
// How much memory one input may make hisnegs allocate, checked before a large
// allocation so that a hostile or mistaken header gets a clear error instead of
// an out-of-memory kill.
#pragma once

#include <filesystem>
#include <optional>
#include <string_view>
#include <string>

namespace hisnegs::io {

// Bytes an input may allocate: HISNEGS_MAX_ALLOC_GB (GiB) if set, else the kernel's
// MemAvailable or, when smaller, the headroom of this process' memory cgroup (its
// tightest limit, v1 or v2, less what the cgroup uses: a Slurm job's --mem, a
// container's limit), else unlimited. `source`, if given, gets where the limit came from.
// Throws InputError if HISNEGS_MAX_ALLOC_GB is not a positive number.
[[nodiscard]] double allocation_limit_bytes(std::string* source = nullptr);

// Throws InputError "PATH: would need X GiB for WHAT but the limit is Y GiB (source)"
// when `bytes` exceeds allocation_limit_bytes().
void check_allocation(const std::filesystem::path& path, double bytes, const std::string& what);

// A memory size as users write it: "auto" (nullopt), or a positive number with an
// optional unit: B, K/KiB, M/MiB, G/GiB, T/TiB (binary), KB/MB/GB/TB (decimal);
// "1GiB", "512M", "1.5 GB". Throws InputError("FIELD = 'TEXT': ...") otherwise.
[[nodiscard]] std::optional<double> parse_memory_size(std::string_view text, std::string_view field);

// The machine's physical memory in bytes (0 if unknown).
[[nodiscard]] double physical_memory_bytes();

// The tightest memory limit set on a process' cgroup or its ancestors (cgroup v2's
// memory.max or v1's memory.limit_in_bytes, found through `proc_self_cgroup`
// under `sys_fs_cgroup`) and the headroom (limit - usage) at the level with the
// least; nullopt when no level sets a limit. The paths are parameters for tests.
struct CgroupMemory {
  double limit = 0, headroom = 0;
};
[[nodiscard]] std::optional<CgroupMemory> cgroup_memory(
    const std::filesystem::path& proc_self_cgroup = "/proc/self/cgroup",
    const std::filesystem::path& sys_fs_cgroup = "/sys/fs/cgroup");

// The memory this process may use: physical memory, or the memory cgroup's limit
// when that is smaller (0 if neither is known). `source` gets "RAM" or "memory
// cgroup limit".
[[nodiscard]] double usable_memory_bytes(std::string* source = nullptr);

// A memory limit a user gave as `text` (parse_memory_size; `auto` = half of
// usable_memory_bytes(), 8 GiB when that is unknown) and where it came from, for messages:
// "FIELD 1.00 GiB" or "auto: half of 23.54 GiB of RAM".
struct MemoryLimit {
  double bytes = 0;
  std::string source;
};
[[nodiscard]] MemoryLimit resolve_memory_limit(std::string_view text, std::string_view field);

// "1.50 GiB".
[[nodiscard]] std::string gib_text(double bytes);

}  // namespace hisnegs::io
