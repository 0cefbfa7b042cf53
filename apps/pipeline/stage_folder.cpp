// SPDX-License-Identifier: Apache-2.0
// check_stage_folder / clear_stage_folder: walk a stage's folder, refuse what a run
// did not write, remove what it did (deepest first).
#include "apps/pipeline/stage_folder.hpp"

#include <fnmatch.h>
#include <sys/stat.h>

#include <algorithm>
#include <string>
#include <system_error>
#include <vector>

#include "io/atomic_file.hpp"
#include "io/error.hpp"

namespace hisnegs::apps {
namespace {

namespace fs = std::filesystem;

// Names every run folder may hold anywhere: the lock a command takes and the
// temporaries of an interrupted write.
constexpr std::string_view kAlwaysOwned[] = {".hisnegs.lock", ".*.tmp-*"};

bool matches(std::string_view pattern, const std::string& relative, int flags) {
  return ::fnmatch(std::string(pattern).c_str(), relative.c_str(), flags) == 0;
}

// Whether `relative` (a path under the folder) is a name a run writes: a file the
// patterns name, or a folder on the way to one (its path a prefix of a pattern's).
bool owned(const StageFolder& folder, const std::string& relative, bool is_dir) {
  const std::string base = fs::path(relative).filename().string();
  if (!is_dir && std::ranges::any_of(kAlwaysOwned, [&](std::string_view p) { return matches(p, base, 0); })) {
    return true;
  }
  for (const std::string_view pattern : folder.files) {
    if (!is_dir && matches(pattern, relative, FNM_PATHNAME | FNM_PERIOD)) return true;
    if (is_dir) {
      // "checkpoints/epoch_*.ply" -> folder "checkpoints"
      const std::string p(pattern);
      for (std::size_t slash = p.find('/'); slash != std::string::npos; slash = p.find('/', slash + 1)) {
        if (matches(p.substr(0, slash), relative, FNM_PATHNAME | FNM_PERIOD)) return true;
      }
    }
  }
  return false;
}

// Every entry under `root`, parents before children; symlinks are not followed.
std::vector<fs::directory_entry> entries_under(const fs::path& root) {
  std::vector<fs::directory_entry> all;
  std::error_code ec;
  for (fs::recursive_directory_iterator it(root, fs::directory_options::none, ec), end; !ec && it != end;
       it.increment(ec)) {
    all.push_back(*it);
  }
  if (ec) io::fail_input(root, "cannot list: " + ec.message());
  return all;
}

}  // namespace

void check_stage_folder(const fs::path& dir, const StageFolder& folder, const fs::path& input) {
  const fs::path root = dir / folder.name;
  std::error_code ec;
  const fs::file_status status = fs::symlink_status(root, ec);
  if (ec || !fs::exists(status)) return;
  const std::string why = std::string("not written by hisnegs run (the ") + folder.name + " stage starts " +
                          root.string() + " over); move it out of the run folder or use another -o";
  if (!fs::is_directory(status)) io::fail_input(root, why);
  for (const fs::directory_entry& e : entries_under(root)) {
    const fs::file_status s = e.symlink_status();
    const std::string relative = e.path().lexically_relative(root).string();
    const bool is_dir = fs::is_directory(s);
    if (!is_dir && (io::is_protected_input(e.path()) || (!input.empty() && io::same_file(e.path(), input)))) {
      io::fail_input(e.path(), std::string("is an input of this run; the ") + folder.name + " stage starts " +
                                   root.string() + " over: move the input out of the run folder");
    }
    if (!(is_dir || fs::is_regular_file(s)) || !owned(folder, relative, is_dir)) io::fail_input(e.path(), why);
  }
}

void clear_stage_folder(const fs::path& dir, const StageFolder& folder, const fs::path& input) {
  check_stage_folder(dir, folder, input);
  const fs::path root = dir / folder.name;
  if (!fs::is_directory(fs::symlink_status(root))) return;
  std::vector<fs::directory_entry> all = entries_under(root);
  std::reverse(all.begin(), all.end());  // children before their folder
  std::error_code ec;  // a folder goes only once it is empty (it is, unless something was added since the check)
  for (const fs::directory_entry& e : all) {
    if (fs::is_directory(e.symlink_status())) {
      fs::remove(e.path(), ec);
    } else {
      fs::remove(e.path());
    }
  }
  fs::remove(root, ec);
}

namespace {
std::optional<io::FolderLock> run_folder_lock(const std::filesystem::path& dir) {
  const std::filesystem::path run = dir.lexically_normal().parent_path();
  std::error_code ec;
  if (run.empty() || !std::filesystem::is_regular_file(run / "run.json", ec)) return std::nullopt;
  return std::optional<io::FolderLock>(std::in_place, run);
}
}  // namespace

OutputFolderLock::OutputFolderLock(const std::filesystem::path& dir) : run_(run_folder_lock(dir)), own_(dir) {}

}  // namespace hisnegs::apps
