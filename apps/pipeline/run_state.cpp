// SPDX-License-Identifier: Apache-2.0
// RunState (DIR/run.json), hash_hex and file_identity.
#include "apps/pipeline/run_state.hpp"

#include <sys/stat.h>

#include <cerrno>
#include <system_error>

#include "apps/pipeline/format.hpp"
#include "io/atomic_file.hpp"
#include "io/error.hpp"
#include "io/hash.hpp"
#include "io/stack_file.hpp"

namespace hisnegs::apps {

namespace fs = std::filesystem;

RunState::RunState(const fs::path& dir) : path_(dir / "run.json") {
  if (!fs::exists(path_)) return;
  try {
    state_ = Json::parse(io::read_file(path_));
  } catch (const Json::exception& e) {
    io::fail_input(path_, std::string("not a hisnegs run record (") + e.what() + "); remove it or use --force");
  }
  if (!state_.is_object() || !state_.contains("stages") || !state_["stages"].is_object()) {
    io::fail_input(path_, "not a hisnegs run record (no \"stages\"); remove it or use --force");
  }
}

RunState::Json RunState::stage(const std::string& name) const {
  return state_.contains("stages") && state_["stages"].contains(name) ? state_["stages"][name] : Json::object();
}

std::int64_t RunState::generation(const std::string& name) const {
  return stage(name).value("generation", std::int64_t{-1});
}

void RunState::set(const std::string& name, Json record) {
  if (record.value("state", "") == "done") {
    const std::int64_t g = state_.value("generation", std::int64_t{0}) + 1;
    state_["generation"] = g;
    record["generation"] = g;
  }
  state_["stages"][name] = std::move(record);
  save();
}

void RunState::set_field(const std::string& key, Json value) {
  state_[key] = std::move(value);
  save();
}

void RunState::save() const {
  const std::string text = state_.dump(2) + "\n";
  io::write_file_atomic(path_, text.data(), text.size());
}

std::string hash_hex(const std::string& text) {
  return strf("%016llx", static_cast<unsigned long long>(io::fnv1a64(text)));
}

namespace {
std::string stat_identity(const fs::path& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    throw fs::filesystem_error("cannot stat", path, std::error_code(errno, std::generic_category()));
  }
  const long long mtime_ns = static_cast<long long>(st.st_mtim.tv_sec) * 1000000000LL + st.st_mtim.tv_nsec;
  return std::to_string(st.st_size) + "|" + std::to_string(mtime_ns) + "|" + std::to_string(st.st_dev) + ":" +
         std::to_string(st.st_ino);
}
}  // namespace

std::string file_content_identity(const fs::path& path) {
  std::string identity = stat_identity(path);
  const std::vector<fs::path> files = io::stack_files(path);  // BigDataViewer: an .xml and the .h5 it names
  std::error_code ec;
  for (std::size_t i = 1; i < files.size(); ++i) {
    identity += "|" + (fs::exists(files[i], ec) ? stat_identity(files[i]) : std::string("missing"));
  }
  return identity;
}

std::string file_identity(const fs::path& path) {
  return fs::absolute(path).lexically_normal().string() + "|" + file_content_identity(path);
}

}  // namespace hisnegs::apps
