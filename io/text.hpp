// SPDX-License-Identifier: Apache-2.0
// Text of numbers for progress lines and reports: printf into a std::string,
// durations and byte counts. Knows no table, file or stage.
#pragma once

#include <cstdarg>
#include <string>

namespace hisnegs::io {

// printf-style formatting into a std::string ("%.2f" etc.), any length.
[[nodiscard]] std::string strf(const char* format, ...) __attribute__((format(printf, 1, 2)));
[[nodiscard]] std::string vstrf(const char* format, va_list args);

// "1.23 s" / "456.0 ms" / "2.5 min".
[[nodiscard]] std::string format_seconds(double seconds);

// "12.3 MiB".
[[nodiscard]] std::string format_bytes(double bytes);

}  // namespace hisnegs::io
