// SPDX-License-Identifier: Apache-2.0
// One writer per output folder: an advisory lock (flock) on DIR/.hisnegs.lock held
// for as long as the FolderLock lives, with the holder's pid in the file so a second
// writer can name it. The kernel drops the lock when the holder exits or is killed,
// so a crash never leaves a folder locked. Knows no run folder layout.
#pragma once

#include <filesystem>

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
  int fd_ = -1;
};

}  // namespace hisnegs::io
