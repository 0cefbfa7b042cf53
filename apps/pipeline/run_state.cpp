// SPDX-License-Identifier: Apache-2.0
// RunState (DIR/run.json), hash_hex and file_identity.
#include "apps/pipeline/run_state.hpp"

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

std::string file_content_identity(const fs::path& path) { return io::stack_identity(path).content(); }

std::string file_identity(const fs::path& path) {
  return fs::absolute(path).lexically_normal().string() + "|" + file_content_identity(path);
}

}  // namespace hisnegs::apps
