// SPDX-License-Identifier: Apache-2.0
// AtomicFile: temp file + fsync + rename; read_file. Also require_regular_file and
// number_text from error.hpp.
#include "io/atomic_file.hpp"

#include <fcntl.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <system_error>

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

std::string number_text(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

namespace {
std::atomic<unsigned> g_temp_counter{0};

void fsync_path(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY);
  if (fd < 0) return;  // best effort: the rename below still makes the write atomic
  ::fsync(fd);
  ::close(fd);
}
}  // namespace

AtomicFile::AtomicFile(fs::path target) : target_(std::move(target)) {
  const fs::path parent = target_.has_parent_path() ? target_.parent_path() : fs::path(".");
  std::error_code ec;
  fs::create_directories(parent, ec);
  if (ec) fail_input(parent, "cannot create output folder: " + ec.message());
  if (fs::is_directory(target_)) fail_input(target_, "output path is a directory");
  // Built with += (GCC 12 raises a false -Wrestrict on "." + std::string).
  std::string name(".");
  name += target_.filename().string();
  name += ".tmp-";
  name += std::to_string(::getpid());
  name += "-";
  name += std::to_string(g_temp_counter.fetch_add(1));
  temp_ = parent / name;
}

AtomicFile::~AtomicFile() {
  if (!committed_) {
    std::error_code ec;
    fs::remove(temp_, ec);
  }
}

void AtomicFile::commit() {
  if (!fs::exists(temp_)) {
    throw std::runtime_error(target_.string() + ": internal error: nothing was written to commit");
  }
  fsync_path(temp_);
  fault_point("atomic_commit");  // written in full, not yet renamed
  std::error_code ec;
  fs::rename(temp_, target_, ec);
  if (ec) throw std::runtime_error(target_.string() + ": cannot rename temporary file: " + ec.message());
  committed_ = true;
  fsync_path(target_.has_parent_path() ? target_.parent_path() : fs::path("."));
}

void write_file_atomic(const fs::path& target, const void* bytes, std::size_t size) {
  AtomicFile file(target);
  std::FILE* f = std::fopen(file.temp_path().c_str(), "wb");
  if (!f) fail_input(target, std::string("cannot open for writing: ") + std::strerror(errno));
  const std::size_t written = size ? std::fwrite(bytes, 1, size, f) : 0;
  const bool ok = written == size && std::fclose(f) == 0;
  if (!ok) throw std::runtime_error(target.string() + ": write failed: " + std::strerror(errno));
  file.commit();
}

int remove_stale_temporaries(const fs::path& dir) {
  int removed = 0;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    if (name.size() > 1 && name[0] == '.' && name.find(".tmp-") != std::string::npos && entry.is_regular_file(ec)) {
      removed += fs::remove(entry.path(), ec) ? 1 : 0;
    }
  }
  return removed;
}

std::string read_file(const fs::path& path) {
  require_regular_file(path);
  std::ifstream in(path, std::ios::binary);
  if (!in) fail_input(path, "cannot open");
  std::ostringstream s;
  s << in.rdbuf();
  if (in.bad()) fail_input(path, "cannot be read");
  return s.str();
}

}  // namespace hisnegs::io
