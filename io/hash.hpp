// 64-bit FNV-1a of a byte range: a fast, stable fingerprint (not cryptographic)
// for state files and run-folder records.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string_view>

namespace hisnegs::io {

[[nodiscard]] inline std::uint64_t fnv1a64(const void* bytes, std::size_t size,
                                           std::uint64_t h = 1469598103934665603ull) {
  const auto* p = static_cast<const unsigned char*>(bytes);
  for (std::size_t i = 0; i < size; ++i) h = (h ^ p[i]) * 1099511628211ull;
  return h;
}
[[nodiscard]] inline std::uint64_t fnv1a64(std::string_view text) { return fnv1a64(text.data(), text.size()); }

}  // namespace hisnegs::io
