// SPDX-License-Identifier: Apache-2.0
// Implementation of the test helpers: fork/exec with captured stdout/stderr.
#include "tests/test_support.hpp"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace hisnegs::testing {
namespace fs = std::filesystem;

ScratchDir::ScratchDir() {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  std::string name = info ? std::string(info->test_suite_name()) + "." + info->name() : "hisnegs";
  for (char& c : name) {
    if (c == '/') c = '_';
  }
  path_ = fs::temp_directory_path() / ("hisnegs-test-" + std::to_string(::getpid()) + "-" + name);
  fs::remove_all(path_);
  fs::create_directories(path_);
}

ScratchDir::~ScratchDir() {
  std::error_code ec;
  fs::remove_all(path_, ec);
}

std::vector<std::string> ScratchDir::entries() const {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(path_)) names.push_back(e.path().filename().string());
  return names;
}

std::string read_bytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

int csv_data_rows(const fs::path& path) {
  std::ifstream in(path);
  if (!in) return -1;
  int rows = -1;  // the header
  for (std::string line; std::getline(in, line);) ++rows;
  return rows;
}

ShellResult run_shell(const std::string& command) {
  ShellResult r;
  FILE* pipe = ::popen((command + " 2>&1").c_str(), "r");
  if (!pipe) return r;
  char buf[4096];
  for (std::size_t n; (n = std::fread(buf, 1, sizeof buf, pipe)) > 0;) r.out.append(buf, n);
  r.status = ::pclose(pipe);
  return r;
}

std::string shell_quoted(const fs::path& path) { return "'" + path.string() + "'"; }

namespace {
// The build's path, or the environment's when set (the device bundle moves both).
fs::path from_env_or(const char* name, const char* built_in) {
  const char* env = std::getenv(name);
  return env && *env ? fs::path(env) : fs::path(built_in);
}
}  // namespace

fs::path hisnegs_exe() { return from_env_or("HISNEGS_TEST_EXE", HISNEGS_EXE); }
fs::path source_dir() { return from_env_or("HISNEGS_TEST_SOURCE_DIR", HISNEGS_SOURCE_DIR); }

CommandResult run_hisnegs(const std::vector<std::string>& args) {
  const fs::path tmp =
      fs::temp_directory_path() / ("hisnegs-run-" + std::to_string(::getpid()) + "-" + std::to_string(::rand()));
  const fs::path out_path = tmp.string() + ".out", err_path = tmp.string() + ".err";
  const pid_t pid = ::fork();
  if (pid < 0) throw std::runtime_error("fork failed");
  if (pid == 0) {
    std::vector<char*> argv;
    std::string exe = hisnegs_exe().string();
    argv.push_back(exe.data());
    std::vector<std::string> copy = args;
    for (auto& a : copy) argv.push_back(a.data());
    argv.push_back(nullptr);
    if (!std::freopen(out_path.c_str(), "w", stdout) || !std::freopen(err_path.c_str(), "w", stderr)) _exit(127);
    ::execv(exe.c_str(), argv.data());
    _exit(127);
  }
  int status = 0;
  ::waitpid(pid, &status, 0);
  CommandResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  r.out = read_bytes(out_path);
  r.err = read_bytes(err_path);
  fs::remove(out_path);
  fs::remove(err_path);
  return r;
}

std::optional<fs::path> shared_data(const std::string& name) {
  const char* env = std::getenv("HISNEGS_TEST_SHARED_DATA");
  const fs::path p = fs::path(env && *env ? env : HISNEGS_SHARED_DATA_DIR) / name;
  if (fs::exists(p)) return p;
  return std::nullopt;
}

ScopedEnv::ScopedEnv(const char* name, const char* value) : name_(name) {
  if (const char* old = std::getenv(name)) previous_ = old;
  ::setenv(name, value, 1);
}

ScopedEnv::~ScopedEnv() {
  if (previous_) {
    ::setenv(name_.c_str(), previous_->c_str(), 1);
  } else {
    ::unsetenv(name_.c_str());
  }
}

void write_text(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

int count_lines(const std::string& text) {
  if (text.empty()) return 0;
  int n = 0;
  for (char c : text) n += (c == '\n');
  if (text.back() != '\n') ++n;
  return n;
}

}  // namespace hisnegs::testing
