// SPDX-License-Identifier: Apache-2.0
// console_progress: Progress lines to stdout, the meter to stderr.
#include "apps/cli/console_progress.hpp"

#include <unistd.h>

#include <cstdio>

#include "apps/pipeline/distributed.hpp"

namespace hisnegs::apps {

Progress console_progress(bool quiet) {
  if (quiet) return {};
  Progress progress;
  progress.line = [](std::string_view line) {
    std::fwrite(line.data(), 1, line.size(), stdout);
    std::fputc('\n', stdout);
    std::fflush(stdout);
  };
  const bool tty = ::isatty(STDERR_FILENO);
  progress.meter = [tty](std::string_view text, bool last) {
    if (!tty && !last) return;  // a log file gets the final count only
    std::fprintf(stderr, "%s%.*s%s", tty ? "\r" : "", static_cast<int>(text.size()), text.data(), last ? "\n" : "");
  };
  const Job& ranks = job();
  if (!ranks.root()) {  // rank 0 tells the story; the others only what they did (their bricks)
    progress.line = [prefix = rank_prefix(ranks)](std::string_view line) {
      if (line.find(": brick ") == std::string_view::npos) return;
      std::printf("%s%.*s\n", prefix.c_str(), static_cast<int>(line.size()), line.data());
      std::fflush(stdout);
    };
    progress.meter = {};
  }
  return progress;
}

}  // namespace hisnegs::apps
