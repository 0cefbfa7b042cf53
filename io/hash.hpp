// SPDX-License-Identifier: Apache-2.0
// 64-bit FNV-1a of a byte range: a fast, stable fingerprint (not cryptographic)
// for state files and run-folder records.
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

}  // namespace hisnegs::io
