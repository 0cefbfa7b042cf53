// SPDX-License-Identifier: Apache-2.0
// strf, format_seconds and format_bytes.
#include "io/text.hpp"

#include <cstdio>

namespace hisnegs::io {

std::string vstrf(const char* format, va_list args) {
  va_list measure;
  va_copy(measure, args);
  const int n = std::vsnprintf(nullptr, 0, format, measure);
  va_end(measure);
  if (n <= 0) return {};
  std::string text(static_cast<std::size_t>(n) + 1, '\0');
  std::vsnprintf(text.data(), text.size(), format, args);
  text.resize(static_cast<std::size_t>(n));
  return text;
}

std::string strf(const char* format, ...) {
  va_list args;
  va_start(args, format);
  std::string text = vstrf(format, args);
  va_end(args);
  return text;
}

std::string format_seconds(double seconds) {
  if (seconds < 1.0) return strf("%.1f ms", seconds * 1e3);
  if (seconds < 120.0) return strf("%.2f s", seconds);
  return strf("%.1f min", seconds / 60.0);
}

std::string format_bytes(double bytes) {
  if (bytes < 1024.0 * 1024.0) return strf("%.1f KiB", bytes / 1024.0);
  if (bytes < 1024.0 * 1024.0 * 1024.0) return strf("%.1f MiB", bytes / (1024.0 * 1024.0));
  return strf("%.2f GiB", bytes / (1024.0 * 1024.0 * 1024.0));
}

}  // namespace hisnegs::io
