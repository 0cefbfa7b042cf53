// SPDX-License-Identifier: Apache-2.0
// FolderLock: flock(LOCK_EX | LOCK_NB) on DIR/.hisnegs.lock, shared within a process.
#include "io/folder_lock.hpp"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <map>
#include <mutex>
#include <string>
#include <system_error>
#include <utility>

#include "io/error.hpp"

namespace hisnegs::io {
namespace {

// The locks this process holds, by the lock file's device and inode: a second
// FolderLock on a held folder shares the first's descriptor (flock locks of two
// descriptors conflict even within one process).
struct HeldLock {
  int fd = -1;
  int count = 0;
};
std::mutex g_held_mutex;
std::map<std::pair<dev_t, ino_t>, HeldLock> g_held;

// Takes the lock on an open lock file, or throws naming its holder.
void take(int& fd, const std::filesystem::path& dir, const std::filesystem::path& path) {
  if (::flock(fd, LOCK_EX | LOCK_NB) == 0) return;
  const int err = errno;
  char buf[32] = {};
  const ssize_t n = ::pread(fd, buf, sizeof buf - 1, 0);
  ::close(fd);
  fd = -1;
  if (err != EWOULDBLOCK) fail_input(path, std::string("cannot lock: ") + std::strerror(err));
  std::string holder = n > 0 ? std::string(buf, static_cast<std::size_t>(n)) : std::string();
  while (!holder.empty() && (holder.back() == '\n' || holder.back() == ' ')) holder.pop_back();
  fail_input(dir, "in use by another hisnegs" + (holder.empty() ? std::string() : " (pid " + printable(holder, 20) + ")") +
                      "; wait for it to finish or use another folder");
}

}  // namespace

FolderLock::FolderLock(const std::filesystem::path& dir) : path_(dir / ".hisnegs.lock") {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) fail_input(dir, "cannot create output folder: " + ec.message());
  int fd = ::open(path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC | O_NOFOLLOW, 0644);
  if (fd < 0) fail_input(path_, std::string("cannot create the folder's lock file: ") + std::strerror(errno));
  struct stat st {};
  if (::fstat(fd, &st) != 0) {
    const int err = errno;
    ::close(fd);
    fail_input(path_, std::string("cannot lock: ") + std::strerror(err));
  }
  const std::lock_guard guard(g_held_mutex);
  const auto held = g_held.find({st.st_dev, st.st_ino});
  if (held != g_held.end()) {  // this process holds it already
    ::close(fd);
    ++held->second.count;
    key_ = {st.st_dev, st.st_ino};
    return;
  }
  take(fd, dir, path_);
  const std::string pid = std::to_string(::getpid()) + "\n";
  // The pid is for the message above only; failing to write it does not matter.
  if (::ftruncate(fd, 0) == 0) (void)!::pwrite(fd, pid.data(), pid.size(), 0);
  key_ = {st.st_dev, st.st_ino};
  g_held[key_] = HeldLock{fd, 1};
}

FolderLock::~FolderLock() {
  const std::lock_guard guard(g_held_mutex);
  const auto held = g_held.find(key_);
  if (held == g_held.end() || --held->second.count > 0) return;
  ::close(held->second.fd);  // releases the lock
  g_held.erase(held);
}

}  // namespace hisnegs::io
