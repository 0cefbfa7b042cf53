// SPDX-License-Identifier: Apache-2.0
// The record of a run folder, DIR/run.json: per stage its fingerprint, state
// (started | done), wall time and generation; and the fingerprint hash. Decides
// no reuse rule (run_pipeline.cpp does) and runs no stage.
#pragma once

#include <cstdint>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>

namespace hisnegs::apps {

// DIR/run.json, read when the object is made and rewritten (atomically) on every change.
// Each finished stage gets the next generation, a counter over the folder's life, so
// a stage built on it can tell a redone upstream stage from the one it used.
class RunState {
 public:
  using Json = nlohmann::ordered_json;

  // Reads DIR/run.json if it exists. Throws io::InputError naming the file if it is
  // not a run record.
  explicit RunState(const std::filesystem::path& dir);

  // The record of stage `name` (an empty object if it has none).
  [[nodiscard]] Json stage(const std::string& name) const;
  // The generation at which stage `name` last finished; -1 if it never did.
  [[nodiscard]] std::int64_t generation(const std::string& name) const;
  // Replaces the record of stage `name`; a record with state "done" gets the next generation.
  void set(const std::string& name, Json record);
  // Sets a top-level field (e.g. "volume", or facts a stage reports such as "fit").
  void set_field(const std::string& key, Json value);
  [[nodiscard]] const Json& json() const { return state_; }

 private:
  void save() const;
  std::filesystem::path path_;
  Json state_ = Json{{"hisnegs_run_version", 1}, {"generation", 0}, {"stages", Json::object()}};
};

// 64-bit FNV-1a of `text` as 16 hex digits (a stage's fingerprint of its inputs).
[[nodiscard]] std::string hash_hex(const std::string& text);

// Absolute path, size, modification time and device:inode of a file: a changed or
// replaced input file gets a new identity. Throws std::filesystem::filesystem_error if it is missing.
[[nodiscard]] std::string file_identity(const std::filesystem::path& path);
// Size, modification time (ns) and device:inode of a file, without its path: every
// atomic rewrite (a new inode) or change gives a new value; moving the folder does not.
// For a stack, of every file behind it (io::StackIdentity::content).
[[nodiscard]] std::string file_content_identity(const std::filesystem::path& path);

}  // namespace hisnegs::apps
