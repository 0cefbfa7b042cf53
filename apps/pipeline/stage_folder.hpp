// SPDX-License-Identifier: Apache-2.0
// The folders a run stage starts over (DIR/train, DIR/eval): the names a run
// writes there, the check that nothing else is there, and the removal of exactly
// those files; the lock an output folder takes with its run folder's. Knows no stage.
#pragma once

#include <filesystem>
#include <optional>
#include <span>
#include <string_view>

#include "io/folder_lock.hpp"

namespace hisnegs::apps {

// A folder of a run folder that a stage starts over, and the files a run writes
// in it: fnmatch(3) patterns (FNM_PATHNAME) of paths relative to the folder. The
// folder lock (.hisnegs.lock) and AtomicFile temporaries (.NAME.tmp-PID-N) are
// always a run's own.
struct StageFolder {
  const char* name;                               // in DIR, e.g. "train"
  std::span<const std::string_view> files;        // e.g. "checkpoints/epoch_*.ply"
};

// Throws io::InputError naming the first entry under DIR/folder.name that a run
// did not write, in one line ("DIR/train/notes.txt: not written by hisnegs run
// (the train stage starts DIR/train over); move it out of the run folder or use
// another -o"), or that is an input of this command (io::is_protected_input, or
// the same file as `input`). Nothing there, or no such folder: no error.
void check_stage_folder(const std::filesystem::path& dir, const StageFolder& folder,
                        const std::filesystem::path& input);

// check_stage_folder, then removes every file under DIR/folder.name and the folders
// left empty (DIR/folder.name itself included). Never removes anything the check refuses.
void clear_stage_folder(const std::filesystem::path& dir, const StageFolder& folder,
                        const std::filesystem::path& input);

// One writer per output folder and per run folder: the lock of `dir` and, when
// `dir` is a stage folder of a run (its parent holds run.json), first the run
// folder's lock, so that `train -o R/train` and `run -o R` exclude each other.
// Throws io::InputError naming the folder in use and its holder's pid.
class OutputFolderLock {
 public:
  explicit OutputFolderLock(const std::filesystem::path& dir);

 private:
  std::optional<io::FolderLock> run_;
  io::FolderLock own_;
};

}  // namespace hisnegs::apps
