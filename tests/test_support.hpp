// Shared helpers for the hisnegs tests: per-test scratch folders, running the
// hisnegs executable, locating ../shared/data. No assertions of their own.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

namespace hisnegs::testing {

// A fresh, empty folder unique to the running test (removed when destroyed).
class ScratchDir {
 public:
  ScratchDir();
  ~ScratchDir();
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  [[nodiscard]] const std::filesystem::path& path() const { return path_; }
  [[nodiscard]] std::filesystem::path operator/(const std::string& name) const { return path_ / name; }
  // Names of the entries in the folder (files left behind show up here).
  [[nodiscard]] std::vector<std::string> entries() const;

 private:
  std::filesystem::path path_;
};

struct CommandResult {
  int exit_code = -1;   // the process exit status; 128+N when killed by signal N
  std::string out;      // stdout
  std::string err;      // stderr
};

// Runs the hisnegs executable of this build with `args` (no shell quoting needed).
CommandResult run_hisnegs(const std::vector<std::string>& args);

// ../shared/data/NAME if it exists (tests on real data skip otherwise).
std::optional<std::filesystem::path> shared_data(const std::string& name);

// Writes `text` to `path` (test fixtures).
void write_text(const std::filesystem::path& path, const std::string& text);

// Number of lines in `text` ignoring one trailing newline.
int count_lines(const std::string& text);

}  // namespace hisnegs::testing
