// SPDX-License-Identifier: Apache-2.0
// `hisnegs view` as a child process for the tests that talk to a real server
// (tests/apps/cli/cli_viewer_test.cpp, cli_view_server_test.cpp): its output, its
// port, signals and its exit. No assertions of its own.
#pragma once

#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <string>
#include <vector>

#include "tests/test_support.hpp"

namespace hisnegs::testing {

// `hisnegs view ...` as a child process whose stdout and stderr are one pipe; SIGKILLed
// if still alive.
class ViewProcess {
 public:
  explicit ViewProcess(const std::vector<std::string>& args) {
    int fds[2];
    if (::pipe(fds) != 0) return;
    pid_ = ::fork();
    if (pid_ == 0) {
      ::dup2(fds[1], 1);
      ::dup2(fds[1], 2);  // stderr too: errors and warnings are part of what is checked
      ::close(fds[0]);
      ::close(fds[1]);
      std::vector<std::string> all = {hisnegs_exe().string()};
      all.insert(all.end(), args.begin(), args.end());
      std::vector<char*> argv;
      argv.reserve(all.size() + 1);
      for (std::string& a : all) argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(argv[0], argv.data());
      ::_exit(127);
    }
    ::close(fds[1]);
    out_ = fds[0];
  }
  ~ViewProcess() {
    if (pid_ > 0 && !reaped_) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
    }
    if (out_ >= 0) ::close(out_);
  }
  // Stdout up to the first line containing `needle`, waiting at most `seconds`.
  std::string read_until(const std::string& needle, double seconds) {
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (text_.find(needle) == std::string::npos && std::chrono::steady_clock::now() < end) {
      pollfd p{out_, POLLIN, 0};
      if (::poll(&p, 1, 100) <= 0) continue;
      char buf[1024];
      const ssize_t n = ::read(out_, buf, sizeof buf);
      if (n <= 0) break;
      text_.append(buf, static_cast<std::size_t>(n));
    }
    return text_;
  }
  // Sends `sig` (none for 0) and waits up to `seconds` for the exit; the exit
  // status, or -1 on timeout.
  int stop(int sig, double seconds) {
    if (sig != 0) ::kill(pid_, sig);
    const auto end = std::chrono::steady_clock::now() + std::chrono::duration<double>(seconds);
    while (std::chrono::steady_clock::now() < end) {
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        reaped_ = true;
        return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      }
      ::usleep(20000);
    }
    return -1;
  }
  [[nodiscard]] pid_t pid() const { return pid_; }

 private:
  pid_t pid_ = -1;
  int out_ = -1;
  bool reaped_ = false;
  std::string text_;
};

// The port of a running `view` from its "serving ... at http://HOST:PORT/" line (0 if none).
inline int served_port(const std::string& out, const std::string& host = "127.0.0.1") {
  const std::string prefix = "at http://" + host + ":";
  const std::size_t at = out.find(prefix);
  return at == std::string::npos ? 0 : std::stoi(out.substr(at + prefix.size()));
}

}  // namespace hisnegs::testing
