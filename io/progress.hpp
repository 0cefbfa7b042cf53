// SPDX-License-Identifier: Apache-2.0
// Progress: where long work sends what it would print (the CLI prints it, tests
// collect it, an empty Progress is quiet). Decides no wording and no stream; the
// pipeline's stages and the bricked fit (gmf/bricked/) both report through it.
#pragma once

#include <functional>
#include <string_view>

namespace hisnegs::io {

struct Progress {
  // One finished line without its newline, e.g. "fit: round 1 done: ...". Empty: quiet.
  std::function<void(std::string_view line)> line;
  // A count that replaces its previous text, e.g. "gt train: 12/106 views, ..."; `last`
  // is set on the final one. Empty: not shown.
  std::function<void(std::string_view text, bool last)> meter;

  [[nodiscard]] bool quiet() const { return !line; }
  // Formats printf-style and sends one line; formats nothing when quiet.
  void say(const char* format, ...) const __attribute__((format(printf, 2, 3)));
};

}  // namespace hisnegs::io
