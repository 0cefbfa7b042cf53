// SPDX-License-Identifier: Apache-2.0
// AtomicFile: temp file + fsync + rename; read_file. Also require_regular_file and
// number_text from error.hpp.
#include "io/atomic_file.hpp"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <ctime>
#include <fstream>
#include <mutex>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <system_error>
#include <vector>

#include "io/error.hpp"
#include "io/fault_injection.hpp"

namespace hisnegs::io {
namespace fs = std::filesystem;

void require_regular_file(const fs::path& path) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (ec || !fs::exists(st)) fail_input(path, "no such file");
  if (fs::is_directory(st)) fail_input(path, "is a directory, expected a file");
  if (!fs::is_regular_file(st)) fail_input(path, "is not a regular file");
}

int open_regular_file(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    const int err = errno;
    if (err == ENOENT || err == ENOTDIR) fail_input(path, "no such file");
    fail_input(path, std::string("cannot open: ") + std::strerror(err));
  }
  struct stat st {};
  const char* problem = nullptr;
  if (::fstat(fd, &st) != 0) {
    problem = "cannot be examined (fstat failed)";
  } else if (S_ISDIR(st.st_mode)) {
    problem = "is a directory, expected a file";
  } else if (!S_ISREG(st.st_mode)) {
    problem = "is not a regular file (a FIFO, device or socket)";
  }
  if (problem || ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) & ~O_NONBLOCK) != 0) {
    ::close(fd);
    fail_input(path, problem ? problem : "cannot be read (fcntl failed)");
  }
  return fd;
}

std::string number_text(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

namespace {
std::atomic<unsigned> g_temp_counter{0};

// 0 or the errno of a failing open/fsync/close.
int fsync_path(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return errno;
  int err = ::fsync(fd) == 0 ? 0 : errno;
  if (::close(fd) != 0 && err == 0) err = errno;
  return err;
}
}  // namespace

void fail_write(const fs::path& target, int err) {
  throw WriteError(target.string() + ": cannot write: " + (err ? std::strerror(err) : "write failed"));
}

namespace {
// The temporaries of live AtomicFiles, for the signal handler: fixed slots of
// pointers into the owners' own path strings (no allocation, lock-free).
constexpr int kTempSlots = 256;
std::atomic<const char*> g_live_temps[kTempSlots];

int register_temp(const char* path) {
  for (int i = 0; i < kTempSlots; ++i) {
    const char* expected = nullptr;
    if (g_live_temps[i].compare_exchange_strong(expected, path)) return i;
  }
  return -1;  // more than kTempSlots writes at once: this one is not cleaned on a signal
}

void unregister_temp(int slot) {
  if (slot >= 0) g_live_temps[slot].store(nullptr);
}

std::mutex g_inputs_mutex;
std::set<std::pair<dev_t, ino_t>> g_inputs;  // protect_input()
}  // namespace

void unlink_live_temporaries() noexcept {
  for (auto& slot : g_live_temps) {
    if (const char* p = slot.load()) ::unlink(p);
  }
}

void protect_input(const fs::path& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return;
  const std::lock_guard lock(g_inputs_mutex);
  g_inputs.emplace(st.st_dev, st.st_ino);
}

bool is_protected_input(const fs::path& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return false;
  const std::lock_guard lock(g_inputs_mutex);
  return g_inputs.count({st.st_dev, st.st_ino}) != 0;
}

bool same_file(const fs::path& a, const fs::path& b) {
  struct stat sa {}, sb {};
  return ::stat(a.c_str(), &sa) == 0 && ::stat(b.c_str(), &sb) == 0 && sa.st_dev == sb.st_dev &&
         sa.st_ino == sb.st_ino;
}

fs::path require_replaceable_output(const fs::path& target) {
  struct stat link {};
  if (::lstat(target.c_str(), &link) != 0) return target;  // nothing there yet
  fs::path path = target;
  struct stat st = link;
  if (S_ISLNK(link.st_mode)) {
    if (::stat(target.c_str(), &st) != 0) fail_input(target, "is a symlink to nothing; refusing to replace it");
    std::error_code ec;
    path = fs::canonical(target, ec);
    if (ec) fail_input(target, "cannot resolve the symlink: " + ec.message());
  }
  if (S_ISDIR(st.st_mode)) fail_input(target, "output path is a directory");
  if (!S_ISREG(st.st_mode)) {
    fail_input(target, "exists and is not a regular file (a device, FIFO or socket); refusing to replace it");
  }
  const std::lock_guard lock(g_inputs_mutex);
  if (g_inputs.count({st.st_dev, st.st_ino}) != 0) {
    fail_input(target, "is also an input of this command; refusing to overwrite it (choose another output)");
  }
  return path;
}

AtomicFile::AtomicFile(const fs::path& target) : target_(require_replaceable_output(target)) {
  const fs::path parent = target_.has_parent_path() ? target_.parent_path() : fs::path(".");
  std::error_code ec;
  fs::create_directories(parent, ec);
  if (ec) fail_input(parent, "cannot create output folder: " + ec.message());
  // Built with += (GCC 12 raises a false -Wrestrict on "." + std::string).
  std::string name(".");
  name += target_.filename().string();
  name += ".tmp-";
  name += std::to_string(::getpid());
  name += "-";
  name += std::to_string(g_temp_counter.fetch_add(1));
  temp_ = parent / name;
  slot_ = register_temp(temp_.c_str());
}

AtomicFile::~AtomicFile() {
  unregister_temp(slot_);
  if (!committed_) {
    std::error_code ec;
    fs::remove(temp_, ec);
  }
}

void AtomicFile::commit() {
  if (!fs::exists(temp_)) {
    throw std::runtime_error(target_.string() + ": internal error: nothing was written to commit");
  }
  if (const int err = fsync_path(temp_); err != 0) fail_write(target_, err);
  fault_point("atomic_commit");  // written in full, not yet renamed
  std::error_code ec;
  fs::rename(temp_, target_, ec);
  if (ec) throw std::runtime_error(target_.string() + ": cannot rename temporary file: " + ec.message());
  committed_ = true;
  unregister_temp(slot_);  // the name is the target's now: a signal must not remove it
  slot_ = -1;
  // The folder's entry: best effort (some file systems refuse fsync on a directory).
  (void)fsync_path(target_.has_parent_path() ? target_.parent_path() : fs::path("."));
}

void write_file_atomic(const fs::path& target, const void* bytes, std::size_t size) {
  AtomicFile file(target);
  std::FILE* f = std::fopen(file.temp_path().c_str(), "wb");
  if (!f) fail_input(target, std::string("cannot open for writing: ") + std::strerror(errno));
  errno = 0;
  const std::size_t written = size ? std::fwrite(bytes, 1, size, f) : 0;
  int err = written == size && std::fflush(f) == 0 ? 0 : (errno ? errno : EIO);
  if (std::fclose(f) != 0 && err == 0) err = errno ? errno : EIO;
  if (err != 0) fail_write(target, err);
  file.commit();
}

namespace {
// The PID of an AtomicFile temporary name ".NAME.tmp-PID-N"; 0 when it is not one.
pid_t temporary_owner(const std::string& name) {
  if (name.size() < 2 || name[0] != '.') return 0;
  const std::size_t at = name.rfind(".tmp-");
  if (at == std::string::npos || at == 0) return 0;
  const std::size_t dash = name.find('-', at + 5);
  if (dash == std::string::npos) return 0;
  try {
    const long pid = std::stol(name.substr(at + 5, dash - at - 5));
    return pid > 0 ? static_cast<pid_t>(pid) : 0;
  } catch (const std::exception&) {
    return 0;
  }
}

bool process_exists(pid_t pid) { return ::kill(pid, 0) == 0 || errno != ESRCH; }

int remove_stale_in(const fs::path& dir, bool recursive) {
  int removed = 0;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    if (entry.is_symlink(ec)) continue;
    if (recursive && entry.is_directory(ec)) {
      removed += remove_stale_in(entry.path(), true);
      continue;
    }
    const pid_t owner = temporary_owner(entry.path().filename().string());
    if (owner == 0 || !entry.is_regular_file(ec) || process_exists(owner)) continue;
    removed += fs::remove(entry.path(), ec) ? 1 : 0;
  }
  return removed;
}
}  // namespace

int remove_stale_temporaries(const fs::path& dir, bool recursive) { return remove_stale_in(dir, recursive); }

std::string read_file(const fs::path& path) {
  const int fd = open_regular_file(path);
  std::string bytes;
  char buffer[1 << 16];
  for (;;) {
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      const int err = errno;
      ::close(fd);
      fail_input(path, std::string("cannot be read: ") + std::strerror(err));
    }
    if (n == 0) break;
    bytes.append(buffer, static_cast<std::size_t>(n));
  }
  ::close(fd);
  return bytes;
}

}  // namespace hisnegs::io
