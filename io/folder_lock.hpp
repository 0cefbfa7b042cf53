// SPDX-License-Identifier: Apache-2.0
// One writer per output folder: an advisory lock (flock) on DIR/.hisnegs.lock held
// for as long as the FolderLock lives, with the holder's pid in the file so a second
// writer can name it. The kernel drops the lock when the holder exits or is killed,
// so a crash never leaves a folder locked. Within one process the lock is shared:
// a second FolderLock on a folder this process holds succeeds (a run's stage may
// lock the run folder its driver holds). Knows no run folder layout.
#pragma once

#include <sys/types.h>

#include <filesystem>
#include <utility>

namespace hisnegs::io {

class FolderLock {
 public:
  // Creates `dir` if needed and takes the lock without waiting. Throws InputError
  // "DIR: in use by another hisnegs (pid N); wait for it or use another folder"
  // when another process holds it, InputError naming the lock file when it cannot
  // be created.
  explicit FolderLock(const std::filesystem::path& dir);
  ~FolderLock();
  FolderLock(const FolderLock&) = delete;
  FolderLock& operator=(const FolderLock&) = delete;

  [[nodiscard]] const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
  std::pair<dev_t, ino_t> key_{};  // the lock file's identity in this process's table
};

}  // namespace hisnegs::io
