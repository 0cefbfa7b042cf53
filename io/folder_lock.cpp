// SPDX-License-Identifier: Apache-2.0
// FolderLock: flock(LOCK_EX | LOCK_NB) on DIR/.hisnegs.lock.
#include "io/folder_lock.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <string>
#include <system_error>

#include "io/error.hpp"

namespace hisnegs::io {

FolderLock::FolderLock(const std::filesystem::path& dir) : path_(dir / ".hisnegs.lock") {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) fail_input(dir, "cannot create output folder: " + ec.message());
  fd_ = ::open(path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0644);
  if (fd_ < 0) fail_input(path_, std::string("cannot create the folder's lock file: ") + std::strerror(errno));
  if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    char buf[32] = {};
    const ssize_t n = ::pread(fd_, buf, sizeof buf - 1, 0);
    ::close(fd_);
    fd_ = -1;
    if (err != EWOULDBLOCK) fail_input(path_, std::string("cannot lock: ") + std::strerror(err));
    std::string holder = n > 0 ? std::string(buf, static_cast<std::size_t>(n)) : std::string();
    while (!holder.empty() && (holder.back() == '\n' || holder.back() == ' ')) holder.pop_back();
    fail_input(dir, "in use by another hisnegs" + (holder.empty() ? std::string() : " (pid " + printable(holder, 20) + ")") +
                        "; wait for it to finish or use another folder");
  }
  const std::string pid = std::to_string(::getpid()) + "\n";
  // The pid is for the message above only; failing to write it does not matter.
  if (::ftruncate(fd_, 0) == 0) (void)!::pwrite(fd_, pid.data(), pid.size(), 0);
}

FolderLock::~FolderLock() {
  if (fd_ >= 0) ::close(fd_);  // releases the lock
}

}  // namespace hisnegs::io
