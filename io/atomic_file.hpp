// SPDX-License-Identifier: Apache-2.0
// Whole-file I/O: atomic output files (write to a temporary name in the target's
// folder, then rename over the target, so a crash never leaves a half-written
// output) and reading a whole file. Does not know any file format.
#pragma once

#include <filesystem>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace hisnegs::io {

// Owns a temporary path beside `target`. Write the file at temp_path(), then
// call commit(); if the object is destroyed without commit() (an exception, an
// early return) the temporary file is removed and `target` is untouched.
class AtomicFile {
 public:
  // Checks the target with require_replaceable_output (a symlink to a regular file
  // is followed: the file it names is replaced, the link stays) and creates its
  // parent folders if needed; throws InputError if either fails.
  explicit AtomicFile(const std::filesystem::path& target);
  ~AtomicFile();
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;

  // Where to write: "<target-folder>/.<target-name>.tmp-<pid>-<n>".
  [[nodiscard]] const std::filesystem::path& temp_path() const { return temp_; }
  [[nodiscard]] const std::filesystem::path& target() const { return target_; }

  // fsyncs the temporary file (a failing fsync, e.g. ENOSPC or EIO on delayed
  // allocation, is an error) and renames it onto the target (atomic on POSIX).
  // Throws std::runtime_error naming the target on failure.
  void commit();

 private:
  std::filesystem::path target_;
  std::filesystem::path temp_;
  bool committed_ = false;
  int slot_ = -1;  // in the signal handler's list of live temporaries
};

// What an output may replace: nothing, or a regular file (through symlinks) that is
// not one of the command's inputs (protect_input). Throws InputError naming `target`
// for a device, FIFO, socket or folder, a dangling symlink, or a protected input.
// Returns the path to write: `target`, or the regular file a symlink resolves to.
std::filesystem::path require_replaceable_output(const std::filesystem::path& target);

// Marks the existing regular file `path` (by device and inode, so any name of it
// counts) as an input of this process: no AtomicFile may replace it. The CLI marks
// every file named on the command line except the outputs. Thread-safe.
void protect_input(const std::filesystem::path& path);

// Whether the existing file `path` (by device and inode, links followed) was marked
// by protect_input. Thread-safe.
[[nodiscard]] bool is_protected_input(const std::filesystem::path& path);

// Whether `a` and `b` exist and are the same file (device and inode).
[[nodiscard]] bool same_file(const std::filesystem::path& a, const std::filesystem::path& b);

// Throws io::WriteError "TARGET: cannot write: <strerror(err)>" (err 0: "write
// failed"): what every writer says when the disk is full or the device fails.
[[noreturn]] void fail_write(const std::filesystem::path& target, int err);

// Removes the temporary file of every AtomicFile alive at this moment
// (async-signal-safe: unlink only): what a signal handler calls before it exits
// (apps/pipeline/interrupts.hpp installs one).
void unlink_live_temporaries() noexcept;

// Writes `bytes` to `target` atomically.
void write_file_atomic(const std::filesystem::path& target, const void* bytes, std::size_t size);

// Removes the temporary files AtomicFile leaves in `dir` (and, when `recursive`,
// its subfolders) when a process is killed between writing and renaming
// ("."NAME".tmp-PID-N") whose process PID no longer exists; returns how many.
// Temporaries of live processes (this one included) are kept.
int remove_stale_temporaries(const std::filesystem::path& dir, bool recursive = false);

// The bytes of the regular file `path`; throws InputError naming it if it is
// missing, not a regular file or cannot be read.
[[nodiscard]] std::string read_file(const std::filesystem::path& path);

}  // namespace hisnegs::io
