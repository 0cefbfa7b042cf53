// SPDX-License-Identifier: Apache-2.0
// 64-bit FNV-1a of a byte range: a fast, stable fingerprint (not cryptographic)
// for state files and run-folder records; splitmix64, a counter-based mix for
// reproducible random streams that do not depend on the order (or thread) in
// which values are drawn.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>

namespace hisnegs::io {

// FNV-1a with the reference 64-bit offset basis 0xcbf29ce484222325 and prime
// 0x100000001b3 (fnv1a64("") == 0xcbf29ce484222325, fnv1a64("a") ==
// 0xaf63dc4c8601ec8c). `h` continues a hash: fnv1a64(b, n, fnv1a64(a)) hashes a + b.
[[nodiscard]] inline std::uint64_t fnv1a64(const void* bytes, std::size_t size,
                                           std::uint64_t h = 0xcbf29ce484222325ull) {
  const auto* p = static_cast<const unsigned char*>(bytes);
  for (std::size_t i = 0; i < size; ++i) h = (h ^ p[i]) * 0x100000001b3ull;
  return h;
}
[[nodiscard]] inline std::uint64_t fnv1a64(std::string_view text) { return fnv1a64(text.data(), text.size()); }

// Steele, Lea and Flood's SplitMix64 finalizer (the seeding generator of xoshiro).
[[nodiscard]] constexpr std::uint64_t splitmix64(std::uint64_t x) {
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

// A double uniform in [0, 1) from the top 53 bits of a hash.
[[nodiscard]] constexpr double unit_double(std::uint64_t hash) { return static_cast<double>(hash >> 11) * 0x1.0p-53; }

}  // namespace hisnegs::io
