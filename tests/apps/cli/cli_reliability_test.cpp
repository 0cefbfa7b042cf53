// SPDX-License-Identifier: Apache-2.0
// Issue 19's data-loss cases through the real executable: a full disk is an error
// and leaves nothing, a run folder has one writer, outputs never replace special
// files or inputs, a signal removes unfinished outputs, and a folder another
// process wrote into is not reused.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/file.h>
#include <sys/mount.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "apps/pipeline/stage_folder.hpp"
#include "gmf/core/checkpoint.hpp"
#include "io/atomic_file.hpp"
#include "io/folder_lock.hpp"
#include "tests/test_support.hpp"

namespace hisnegs {
namespace {
namespace fs = std::filesystem;
using testing::CommandResult;
using testing::run_hisnegs;

// Files whose name marks an AtomicFile temporary, anywhere under `dir`.
int temporaries_under(const fs::path& dir) {
  int n = 0;
  for (const auto& e : fs::recursive_directory_iterator(dir)) {
    n += e.path().filename().string().find(".tmp-") != std::string::npos ? 1 : 0;
  }
  return n;
}

// A 16 KiB tmpfs at `path` for the life of the object (needs root or
// CAP_SYS_ADMIN, as CI has; mounted() is false otherwise).
class SmallDisk {
 public:
  explicit SmallDisk(const fs::path& path) : path_(path) {
    fs::create_directories(path);
    mounted_ = ::mount("tmpfs", path.c_str(), "tmpfs", 0, "size=16k") == 0;
  }
  ~SmallDisk() {
    if (mounted_) ::umount(path_.c_str());
  }
  SmallDisk(const SmallDisk&) = delete;
  SmallDisk& operator=(const SmallDisk&) = delete;
  [[nodiscard]] bool mounted() const { return mounted_; }

 private:
  fs::path path_;
  bool mounted_ = false;
};

class Reliability : public ::testing::Test {
 protected:
  testing::ScratchDir dir_;

  void SetUp() override {
    ASSERT_EQ(run_hisnegs({"-q", "synth", "-o", dir_ / "v.tif", "--shape", "16,40,40"}).exit_code, 0);
    gmf::GaussianMixture mixture;
    for (int k = 0; k < 20; ++k) {
      gmf::GaussianParams g;
      g.mean = {0.05f * k - 0.5f, 0.02f * k, -0.1f};
      g.log_scale = {-3.0f, -2.5f, -2.8f};
      g.intensity_logit = 0.5f;
      mixture.push_back(g);
    }
    gmf::CheckpointMeta meta;
    meta.volume_shape_zyx = std::array<int, 3>{40, 64, 64};
    meta.aspect = std::array<double, 3>{1.0, 1.0, 0.625};
    gmf::save_checkpoint(dir_ / "m.ply", mixture, meta);
  }

  // Expects exit `code`, one stderr line containing `needle`.
  static void expect_refused(const CommandResult& r, int code, const std::string& needle) {
    EXPECT_EQ(r.exit_code, code) << r.err;
    EXPECT_EQ(testing::count_lines(r.err), 1) << r.err;
    EXPECT_NE(r.err.find(needle), std::string::npos) << r.err;
  }
};

// A 16 KiB tmpfs (needs root or CAP_SYS_ADMIN, as CI has; skipped otherwise):
// every writer fails with the file and the errno, and leaves nothing there.
TEST_F(Reliability, FullDiskIsAnErrorAndLeavesNothing) {
  const fs::path full = dir_ / "full";
  const SmallDisk disk(full);
  if (!disk.mounted()) GTEST_SKIP() << "cannot mount a tmpfs here";
  const std::vector<std::vector<std::string>> commands = {
      {"vdb", dir_ / "v.tif", "-o", full / "a.vdb"},
      {"export", "vdb", "--points", "--model", dir_ / "m.ply", "-o", full / "p.vdb"},
      {"export", "volume", "--model", dir_ / "m.ply", "-o", full / "v.tif"},
      {"fit", dir_ / "v.tif", "-o", full / "f.ply", "--time-budget", "1"},
  };
  // The checkpoint itself is small: fill the disk first so that it cannot fit either.
  {
    std::ofstream filler(full / "filler", std::ios::binary);
    const std::string block(4096, 'x');
    for (int i = 0; i < 3; ++i) filler << block;
  }
  for (const auto& args : commands) {
    const CommandResult r = run_hisnegs(args);
    SCOPED_TRACE(args[0] + " " + args[1]);
    expect_refused(r, 1, "No space left on device");
    EXPECT_NE(r.err.find(full.string()), std::string::npos) << r.err;
    for (const auto& e : fs::directory_iterator(full)) {
      EXPECT_EQ(e.path().filename(), "filler") << "left behind: " << e.path();
    }
  }
}

TEST_F(Reliability, ARunFolderHasOneWriter) {
  const io::FolderLock held(dir_ / "run");  // as another hisnegs would hold it
  const std::string pid = "(pid " + std::to_string(::getpid()) + ")";
  expect_refused(run_hisnegs({"run", dir_ / "v.tif", "-o", dir_ / "run", "--backend", "cpu"}), 2, pid);
  EXPECT_FALSE(fs::exists(dir_ / "run" / "run.json"));
  const io::FolderLock train(dir_ / "t");
  // train checks its inputs first; give it ground truth so that it reaches the lock.
  ASSERT_EQ(run_hisnegs({"-q", "gt", dir_ / "v.tif", "-o", dir_ / "gt", "--orbit", "both", "--size", "16"}).exit_code,
            0);
  expect_refused(run_hisnegs({"train", "--init", dir_ / "m.ply", "--data", dir_ / "gt", "-o", dir_ / "t",
                              "--backend", "cpu", "--epochs", "1"}),
                 2, "in use by another hisnegs " + pid);
  EXPECT_FALSE(fs::exists(dir_ / "t" / "log.csv"));
}

// A stage folder of a run and the run folder have one writer together: `train -o
// R/train` while `run -o R` holds R is refused, and `run -o R` while a training
// holds R/train (and so R) too. Within one process a held folder may be locked again.
TEST_F(Reliability, AStageFolderAndItsRunFolderHaveOneWriter) {
  {
    const io::FolderLock once(dir_ / "same");
    const io::FolderLock again(dir_ / "same");  // shared, not a conflict
    const int fd = ::open((dir_ / "same" / ".hisnegs.lock").c_str(), O_RDWR);
    ASSERT_GE(fd, 0);
    EXPECT_NE(::flock(fd, LOCK_EX | LOCK_NB), 0) << "held while either lives";
    ::close(fd);
  }
  const int fd = ::open((dir_ / "same" / ".hisnegs.lock").c_str(), O_RDWR);
  ASSERT_GE(fd, 0);
  EXPECT_EQ(::flock(fd, LOCK_EX | LOCK_NB), 0) << "released with the last";
  ::close(fd);

  ASSERT_EQ(run_hisnegs({"-q", "gt", dir_ / "v.tif", "-o", dir_ / "gt", "--orbit", "both", "--size", "16"}).exit_code,
            0);
  fs::create_directories(dir_ / "R");
  testing::write_text(dir_ / "R" / "run.json", "{}");
  const std::string pid = "in use by another hisnegs (pid " + std::to_string(::getpid()) + ")";
  const std::vector<std::string> train = {"train", "--init", dir_ / "m.ply", "--data", dir_ / "gt", "-o",
                                          dir_ / "R" / "train", "--backend", "cpu", "--epochs", "1"};
  {
    const io::FolderLock run(dir_ / "R");  // as `run -o R` holds it
    expect_refused(run_hisnegs(train), 2, pid);
    EXPECT_FALSE(fs::exists(dir_ / "R" / "train" / "log.csv"));
  }
  {
    const apps::OutputFolderLock training(dir_ / "R" / "train");  // as `train -o R/train` holds it
    expect_refused(run_hisnegs({"run", dir_ / "v.tif", "-o", dir_ / "R", "--backend", "cpu", "--force"}), 2, pid);
  }
  EXPECT_EQ(testing::read_bytes(dir_ / "R" / "run.json"), "{}");
}

// A FIFO given as a stack is refused at once by every command that reads one (they
// blocked opening it for its HDF5 signature), as `info` and `run` refused it.
TEST_F(Reliability, AFifoAsTheStackIsRefusedAtOnce) {
  ASSERT_EQ(::mkfifo((dir_ / "f.tif").c_str(), 0644), 0);
  expect_refused(run_hisnegs({"fit", dir_ / "f.tif", "-o", dir_ / "x.ply"}), 2, "not a regular file");
  expect_refused(run_hisnegs({"vdb", dir_ / "f.tif", "-o", dir_ / "x.vdb"}), 2, "not a regular file");
  expect_refused(run_hisnegs({"gt", dir_ / "f.tif", "-o", dir_ / "g"}), 2, "not a regular file");
  expect_refused(run_hisnegs({"export", "volume", "--model", dir_ / "m.ply", "--match-volume", dir_ / "f.tif", "-o",
                              dir_ / "x.tif"}),
                 2, "not a regular file");
  EXPECT_FALSE(fs::exists(dir_ / "x.ply"));
  EXPECT_FALSE(fs::exists(dir_ / "x.vdb"));
  EXPECT_FALSE(fs::exists(dir_ / "x.tif"));
}

TEST_F(Reliability, OutputsNeverReplaceSpecialFilesOrInputs) {
  const std::string model = testing::read_bytes(dir_ / "m.ply");
  ASSERT_EQ(::mkfifo((dir_ / "fifo").c_str(), 0644), 0);
  expect_refused(run_hisnegs({"export", "splat-ply", "--model", dir_ / "m.ply", "-o", dir_ / "fifo"}), 2,
                 "not a regular file");
  EXPECT_TRUE(fs::is_fifo(dir_ / "fifo"));
  if (::mknod((dir_ / "null").c_str(), S_IFCHR | 0666, makedev(1, 3)) == 0) {  // root only
    expect_refused(run_hisnegs({"export", "splat-ply", "--model", dir_ / "m.ply", "-o", dir_ / "null"}), 2,
                   "not a regular file");
    EXPECT_TRUE(fs::is_character_file(dir_ / "null"));
  }
  fs::create_symlink(dir_ / "nowhere", dir_ / "dangling");
  expect_refused(run_hisnegs({"export", "splat-ply", "--model", dir_ / "m.ply", "-o", dir_ / "dangling"}), 2,
                 "symlink to nothing");
  // The same file under its own name, a hard link or a symlink: refused, untouched.
  fs::create_hard_link(dir_ / "m.ply", dir_ / "hard.ply");
  fs::create_symlink(dir_ / "m.ply", dir_ / "soft.ply");
  for (const char* out : {"m.ply", "hard.ply", "soft.ply"}) {
    expect_refused(run_hisnegs({"export", "splat-ply", "--model", dir_ / "m.ply", "-o", dir_ / out}), 2,
                   "is also an input (--model)");
  }
  expect_refused(run_hisnegs({"export", "volume", "--model", dir_ / "m.ply", "-o", dir_ / "hard.ply"}), 2,
                 "is also an input");
  const std::string stack = testing::read_bytes(dir_ / "v.tif");
  expect_refused(run_hisnegs({"vdb", dir_ / "v.tif", "-o", dir_ / "v.tif"}), 2, "is also an input (VOLUME)");
  expect_refused(run_hisnegs({"fit", dir_ / "v.tif", "-o", dir_ / "f.ply", "--log", dir_ / "v.tif"}), 2,
                 "is also an input");
  EXPECT_EQ(testing::read_bytes(dir_ / "m.ply"), model);
  EXPECT_EQ(testing::read_bytes(dir_ / "v.tif"), stack);
  EXPECT_FALSE(fs::exists(dir_ / "f.ply"));
  // A symlink to another regular file is followed: that file is replaced, the link stays.
  testing::write_text(dir_ / "old.ply", "old");
  fs::create_symlink(dir_ / "old.ply", dir_ / "link.ply");
  ASSERT_EQ(run_hisnegs({"-q", "export", "splat-ply", "--model", dir_ / "m.ply", "-o", dir_ / "link.ply"}).exit_code,
            0);
  EXPECT_TRUE(fs::is_symlink(dir_ / "link.ply"));
  EXPECT_NE(testing::read_bytes(dir_ / "old.ply"), "old");
}

TEST_F(Reliability, ASignalRemovesUnfinishedOutputs) {
  for (const auto& [fault, code] : {std::pair{"atomic_commit:1:INT", 130}, std::pair{"atomic_commit:1:TERM", 143}}) {
    ::setenv("HISNEGS_FAULT", fault, 1);
    const CommandResult r = run_hisnegs({"export", "splat-ply", "--model", dir_ / "m.ply", "-o", dir_ / "out" / "s.ply"});
    ::unsetenv("HISNEGS_FAULT");
    expect_refused(r, code, "interrupted by SIG");
    EXPECT_FALSE(fs::exists(dir_ / "out" / "s.ply"));
    EXPECT_EQ(temporaries_under(dir_ / "out"), 0);
  }
}

// Issue 32, item 3: a disk with no room even for the TIFF header is a write error
// (exit 1, "No space left on device"), as every other writer reports it.
TEST_F(Reliability, ExportVolumeOnAFullDiskIsAWriteError) {
  const fs::path full = dir_ / "full";
  const SmallDisk disk(full);
  if (!disk.mounted()) GTEST_SKIP() << "cannot mount a tmpfs here";
  {
    std::ofstream filler(full / "filler", std::ios::binary);
    const std::string block(1024, 'x');
    for (int i = 0; i < 64 && filler; ++i) filler << block << std::flush;  // until the disk is full
  }
  const CommandResult r = run_hisnegs({"export", "volume", "--model", dir_ / "m.ply", "-o", full / "v.tif"});
  expect_refused(r, 1, "No space left on device");
  EXPECT_NE(r.err.find((full / "v.tif").string()), std::string::npos) << r.err;
  for (const auto& e : fs::directory_iterator(full)) EXPECT_EQ(e.path().filename(), "filler") << e.path();
}

// Issue 32, item 2: a file named by a global option (--config) is an input too.
TEST_F(Reliability, TheConfigFileIsAnInput) {
  const std::string config = "splat:\n  beta: 50\n";
  testing::write_text(dir_ / "cfg.yaml", config);
  expect_refused(run_hisnegs({"--config", dir_ / "cfg.yaml", "export", "html", "--model", dir_ / "m.ply", "-o",
                              dir_ / "cfg.yaml"}),
                 2, "is also an input (--config)");
  expect_refused(run_hisnegs({"--config", dir_ / "cfg.yaml", "export", "splat-ply", "--model", dir_ / "m.ply", "-o",
                              dir_ / "cfg.yaml"}),
                 2, "is also an input (--config)");
  EXPECT_EQ(testing::read_bytes(dir_ / "cfg.yaml"), config);
}

// Issue 32, item 1: `run` starts DIR/train and DIR/eval over, but removes only what a
// run wrote there; a folder holding anything else (its own input included) is
// refused in one line before the first stage, and nothing is touched.
TEST_F(Reliability, RunNeverRemovesFilesItDidNotWrite) {
  const fs::path p = dir_ / "p";
  fs::create_directories(p / "train");
  fs::copy_file(dir_ / "v.tif", p / "train" / "vol.tif");
  const std::string stack = testing::read_bytes(dir_ / "v.tif");
  expect_refused(run_hisnegs({"run", p / "train" / "vol.tif", "-o", p, "--backend", "cpu"}), 2,
                 "vol.tif: is a file of the run folder " + p.string() + " that the run writes (train)");
  EXPECT_EQ(testing::read_bytes(p / "train" / "vol.tif"), stack);
  EXPECT_FALSE(fs::exists(p / "run.json"));  // refused before any stage

  const fs::path r = dir_ / "r";
  fs::create_directories(r / "eval" / "compare");
  testing::write_text(r / "eval" / "compare" / "000.png", "a run's");
  testing::write_text(r / "eval" / "mine.txt", "mine");
  expect_refused(run_hisnegs({"run", dir_ / "v.tif", "-o", r, "--backend", "cpu"}), 2,
                 "eval/mine.txt: not written by hisnegs run");
  EXPECT_EQ(testing::read_bytes(r / "eval" / "mine.txt"), "mine");
  EXPECT_TRUE(fs::exists(r / "eval" / "compare" / "000.png"));
  fs::create_directories(r / "train" / "checkpoints");
  testing::write_text(r / "train" / "checkpoints" / "notes.txt", "notes");
  expect_refused(run_hisnegs({"run", dir_ / "v.tif", "-o", r, "--backend", "cpu"}), 2,
                 "checkpoints/notes.txt: not written by hisnegs run");
  EXPECT_EQ(testing::read_bytes(r / "train" / "checkpoints" / "notes.txt"), "notes");
  EXPECT_FALSE(fs::exists(r / "run.json"));
}

// Stale temporaries: those of dead processes go, those of live ones stay.
TEST(StaleTemporaries, OnlyThoseOfDeadProcessesAreRemoved) {
  testing::ScratchDir dir;
  const pid_t child = ::fork();
  if (child == 0) ::_exit(0);
  ASSERT_GT(child, 0);
  ::waitpid(child, nullptr, 0);  // its pid now names no process
  fs::create_directories(dir / "sub");
  const std::string dead = ".a.tif.tmp-" + std::to_string(child) + "-0";
  const std::string mine = ".b.tif.tmp-" + std::to_string(::getpid()) + "-3";
  for (const fs::path& p : {dir / dead, dir / mine, dir / "sub" / dead, dir / "keep.tmp-1"}) testing::write_text(p, "x");
  EXPECT_EQ(io::remove_stale_temporaries(dir.path()), 1);
  EXPECT_FALSE(fs::exists(dir / dead));
  EXPECT_TRUE(fs::exists(dir / mine));
  EXPECT_TRUE(fs::exists(dir / "sub" / dead));
  EXPECT_TRUE(fs::exists(dir / "keep.tmp-1"));  // not a hidden AtomicFile name
  EXPECT_EQ(io::remove_stale_temporaries(dir.path(), true), 1);
  EXPECT_FALSE(fs::exists(dir / "sub" / dead));
}

}  // namespace
}  // namespace hisnegs
