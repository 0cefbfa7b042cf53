// SPDX-License-Identifier: Apache-2.0
// Progress::say.
#include "io/progress.hpp"

#include <cstdarg>

#include "io/text.hpp"

namespace hisnegs::io {

void Progress::say(const char* format, ...) const {
  if (!line) return;
  va_list args;
  va_start(args, format);
  const std::string text = vstrf(format, args);
  va_end(args);
  line(text);
}

}  // namespace hisnegs::io
