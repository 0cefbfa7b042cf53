// SPDX-License-Identifier: Apache-2.0
// Whole-file I/O: atomic output files (write to a temporary name in the target's
// folder, then rename over the target, so a crash never leaves a half-written
// output) and reading a whole file. Does not know any file format.
#pragma once

#include <filesystem>
#include <string>

namespace hisnegs::io {

// Owns a temporary path beside `target`. Write the file at temp_path(), then
// call commit(); if the object is destroyed without commit() (an exception, an
// early return) the temporary file is removed and `target` is untouched.
class AtomicFile {
 public:
  // Creates the target's parent folders if needed; throws InputError if that fails.
  explicit AtomicFile(std::filesystem::path target);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  // Where to write: "<target-folder>/.<target-name>.tmp-<pid>-<n>".
  [[nodiscard]] const std::filesystem::path& temp_path() const { return temp_; }
  [[nodiscard]] const std::filesystem::path& target() const { return target_; }

  // fsyncs the temporary file and renames it onto the target (atomic on POSIX).
  // Throws std::runtime_error naming the target on failure.
  void commit();

 private:
  std::filesystem::path target_;
  std::filesystem::path temp_;
  bool committed_ = false;
};

// Writes `bytes` to `target` atomically.
void write_file_atomic(const std::filesystem::path& target, const void* bytes, std::size_t size);

// Removes the temporary files AtomicFile leaves in `dir` when a process is killed
// between writing and renaming ("."NAME".tmp-*"); returns how many. For folders
// one process owns, before it writes there again (e.g. a resumed training).
int remove_stale_temporaries(const std::filesystem::path& dir);

// The bytes of the regular file `path`; throws InputError naming it if it is
// missing, not a regular file or cannot be read.
[[nodiscard]] std::string read_file(const std::filesystem::path& path);

}  // namespace hisnegs::io
