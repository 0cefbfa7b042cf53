// SPDX-License-Identifier: Apache-2.0
// Crash points for the crash-safety tests. With HISNEGS_FAULT=NAME:N in the
// environment, the N-th arrival at fault_point("NAME") kills the process with
// SIGKILL, as an out-of-memory killer or a user's `kill -9` would, so a test can
// check what a crash at that moment leaves behind and that --resume recovers.
// HISNEGS_FAULT=NAME:N:INT (or :TERM) raises SIGINT (SIGTERM) there instead, as a
// user's Ctrl-C (or `kill`) would.
// Without HISNEGS_FAULT (every real run) a fault point is one predictable branch.
#pragma once

namespace hisnegs::io {

void fault_point(const char* name);

}  // namespace hisnegs::io
