// SPDX-License-Identifier: Apache-2.0
// Whether a JSON text nests at most `depth` arrays and objects: checked before
// nlohmann parses it, since copies and dump() of its values recurse (a file of a
// million '[' would overflow the stack). Strings (with escapes) are skipped.
#pragma once

#include <string_view>

namespace hisnegs::io {

[[nodiscard]] inline bool json_nests_within(std::string_view text, int depth) {
  int open = 0;
  bool in_string = false, escaped = false;
  for (const char c : text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
    } else if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      if (++open > depth) return false;
    } else if (c == ']' || c == '}') {
      --open;
    }
  }
  return true;
}

}  // namespace hisnegs::io
