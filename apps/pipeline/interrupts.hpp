// SPDX-License-Identifier: Apache-2.0
// How a hisnegs process ends when it is stopped from outside (Ctrl-C, an MPI
// launcher's SIGTERM): its unfinished outputs removed, what it was doing said,
// and what a rank killed outright left unsaid. io only removes temporaries
// (io::unlink_live_temporaries); the handlers and their notes live here.
#pragma once

#include <filesystem>
#include <string_view>
#include <utility>
#include <vector>

namespace hisnegs::apps {

// Installs handlers for SIGINT, SIGTERM and SIGHUP that remove the temporary
// file of every io::AtomicFile alive at that moment (unlink is async-signal-safe),
// say so in one line and exit 128 + signal (130 for Ctrl-C, 143 for SIGTERM);
// and ignores SIGXFSZ, so exceeding a file-size limit is a write error (EFBIG)
// rather than a core dump. Call once at start-up (the CLI does).
void install_interrupt_cleanup();

// A line those handlers write to stderr before their own, and into the file
// `marker` when it is not empty: what this process was doing when it was stopped
// from outside (an MPI launcher's SIGTERM after another rank died, Ctrl-C). An
// empty `line` clears it. Lines over 1023 bytes and markers over 4095 are cut.
void set_interrupt_note(std::string_view line, const std::filesystem::path& marker = {});

// What those handlers look at after their note, to say what another process left
// unsaid (an MPI rank killed outright cannot speak): `wait_ms` after the signal,
// for each file `said` that exists while its `unless` does not, they write the
// file's second line to stderr, prefixed "hisnegs: ". An empty list clears it.
// (The fit's ranks: `said` = the brick a rank holds, `unless` = the mark its own
// handler leaves when it is stopped rather than killed.)
void set_interrupt_watch(const std::vector<std::pair<std::filesystem::path, std::filesystem::path>>& files,
                         int wait_ms);

}  // namespace hisnegs::apps
