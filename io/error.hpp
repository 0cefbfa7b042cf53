// SPDX-License-Identifier: Apache-2.0
// Exception types of hisnegs. InputError means "the user's input is wrong" (bad
// file, bad option, bad config) and maps to exit status 2 in apps; anything else
// thrown is an internal failure (exit status 1).
#pragma once

#include <filesystem>
#include <stdexcept>
#include <string>
#include <string_view>

namespace hisnegs::io {

// Bad input: a file, option or config value that cannot be used. The message is
// one line and names the file (or option), the field and what was expected.
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// An output could not be written (full disk, I/O error, file size limit): not a
// bug and not bad input; the CLI says "error: PATH: cannot write: REASON", exit 1.
class WriteError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// A long call stopped from outside it (Ctrl-C, or an exception in a caller's
// callback, e.g. a Python optimizer): code that records a failure and goes on (the
// optimizer comparison) passes it through; whoever started the call handles it.
class Interrupted : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// "PATH: message" with the path as the user typed it.
[[nodiscard]] inline std::string describe(const std::filesystem::path& path, const std::string& message) {
  return path.string() + ": " + message;
}

// Throws InputError("PATH: message").
[[noreturn]] inline void fail_input(const std::filesystem::path& path, const std::string& message) {
  throw InputError(describe(path, message));
}

// `text` made fit for a one-line message: line breaks and tabs become spaces,
// other control bytes '?', and text longer than `max_chars` is cut with "...".
// For library messages (OpenVDB, libtiff, JSON) and hostile file content.
[[nodiscard]] inline std::string printable(std::string_view text, std::size_t max_chars = 1000) {
  std::string out;
  out.reserve(text.size() < max_chars ? text.size() : max_chars + 3);
  for (std::size_t i = 0; i < text.size() && i < max_chars; ++i) {
    const auto u = static_cast<unsigned char>(text[i]);
    out += (u == '\n' || u == '\r' || u == '\t') ? ' ' : ((u < 0x20 || u == 0x7F) ? '?' : text[i]);
  }
  if (text.size() > max_chars) out += "...";
  return out;
}

// A number as a user would type it in a message: 6 significant digits, "0.002", "1e-06".
[[nodiscard]] std::string number_text(double v);

// Checks that `path` names an existing regular file; throws InputError naming it
// ("no such file", "is a directory", "is not a regular file") otherwise.
void require_regular_file(const std::filesystem::path& path);

// Opens the regular file `path` for reading without ever blocking on it: O_NONBLOCK
// at open (a FIFO put in its place would otherwise wait for a writer, forever) and
// the checks of require_regular_file on that very descriptor (fstat), so no swap
// between a check and the open gets past. Returns the descriptor (O_CLOEXEC,
// blocking again), which the caller closes. Throws InputError as require_regular_file.
[[nodiscard]] int open_regular_file(const std::filesystem::path& path);

}  // namespace hisnegs::io
