// SPDX-License-Identifier: Apache-2.0
// The command line's Progress sink: lines on stdout, the view meter on stderr
// (redrawn in place on a terminal, printed once when done otherwise).
#pragma once

#include "apps/pipeline/progress.hpp"

namespace hisnegs::apps {

// Quiet: an empty Progress (no lines, no meter).
Progress console_progress(bool quiet);

}  // namespace hisnegs::apps
