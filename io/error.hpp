// Exception types of hisnegs. InputError means "the user's input is wrong" (bad
// file, bad option, bad config) and maps to exit status 2 in apps; anything else
// thrown is an internal failure (exit status 1).
#pragma once

#include <filesystem>
#include <stdexcept>
#include <string>

namespace hisnegs::io {

// Bad input: a file, option or config value that cannot be used. The message is
// one line and names the file (or option), the field and what was expected.
class InputError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// "PATH: message" with the path as the user typed it.
[[nodiscard]] inline std::string describe(const std::filesystem::path& path,
                                          const std::string& message) {
  return path.string() + ": " + message;
}

// Throws InputError("PATH: message").
[[noreturn]] inline void fail_input(const std::filesystem::path& path, const std::string& message) {
  throw InputError(describe(path, message));
}

// Checks that `path` names an existing regular file; throws InputError naming it
// ("no such file", "is a directory", "is not a regular file") otherwise.
void require_regular_file(const std::filesystem::path& path);

}  // namespace hisnegs::io
