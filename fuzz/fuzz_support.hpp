// SPDX-License-Identifier: Apache-2.0
// Shared by the libFuzzer targets: the scratch file each input is written to
// (the readers take paths) and the checks every target applies. No reader here.
#pragma once

#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <system_error>

#include "io/error.hpp"

namespace hisnegs::fuzz {

// A folder of this process under /dev/shm (tmpfs: rewriting a file per input
// costs no disk I/O; the system temp folder where /dev/shm is missing), removed
// at normal exit. A crashed run leaves it behind; it holds only the last input.
class ScratchDir {
 public:
  ScratchDir() {
    std::error_code ec;
    std::filesystem::path base = "/dev/shm";
    if (!std::filesystem::is_directory(base, ec)) base = std::filesystem::temp_directory_path();
    path_ = base / ("hisnegs-fuzz-" + std::to_string(::getpid()));
    std::filesystem::create_directories(path_);
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;

  // `name` inside the folder.
  [[nodiscard]] std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

// The process's scratch folder (created on first use).
inline const ScratchDir& scratch_dir() {
  static const ScratchDir dir;
  return dir;
}

// Writes `size` bytes to scratch_dir() / name (replacing it) and returns the path.
// Aborts if the file cannot be written: that is the harness failing, not the reader.
inline std::filesystem::path write_input(const std::string& name, const std::uint8_t* data, std::size_t size) {
  std::filesystem::path path = scratch_dir() / name;
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f || (size && std::fwrite(data, 1, size, f) != size) || std::fclose(f) != 0) {
    std::fprintf(stderr, "fuzz harness: cannot write %s: %s\n", path.c_str(), std::strerror(errno));
    std::abort();
  }
  return path;
}

// Aborts, naming `what` (and `detail`), when a property the readers promise does
// not hold: libFuzzer records the input as a crash.
inline void require(bool ok, const char* what, const std::string& detail = {}) {
  if (!ok) {
    std::fprintf(stderr, "fuzz harness: broken promise: %s%s%s\n", what, detail.empty() ? "" : ": ", detail.c_str());
    std::abort();
  }
}

// io/error.hpp: an InputError message is one line naming the file.
inline void check_input_error(const io::InputError& e) {
  const char* what = e.what();
  require(*what != '\0', "InputError with an empty message");
  require(std::strpbrk(what, "\r\n") == nullptr, "InputError message is one line",
          io::printable(what) + " (line breaks shown as blanks)");
}

}  // namespace hisnegs::fuzz
