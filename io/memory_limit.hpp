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
// MemAvailable, else unlimited. `source`, if given, gets where the limit came from.
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

// A memory limit a user gave as `text` (parse_memory_size; `auto` = half the
// machine's RAM, 8 GiB when that is unknown) and where it came from, for messages:
// "FIELD 1.00 GiB" or "auto: half of 23.54 GiB of RAM".
struct MemoryLimit {
  double bytes = 0;
  std::string source;
};
[[nodiscard]] MemoryLimit resolve_memory_limit(std::string_view text, std::string_view field);

// "1.50 GiB".
[[nodiscard]] std::string gib_text(double bytes);

}  // namespace hisnegs::io
