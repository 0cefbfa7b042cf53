// SPDX-License-Identifier: Apache-2.0
// The process's answer to SIGINT, SIGTERM and SIGHUP: io's live temporaries
// removed, the note and the watched lines written (async-signal-safe calls only),
// one line, exit 128 + signal.
#include "apps/pipeline/interrupts.hpp"

#include <fcntl.h>
#include <signal.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <cstring>
#include <ctime>
#include <deque>
#include <mutex>
#include <string>
#include <vector>

#include "io/atomic_file.hpp"

namespace hisnegs::apps {
namespace fs = std::filesystem;
namespace {

// set_interrupt_note's line and marker: two slots, the one in use published by
// index after it is written, so the handler never reads a half-written one.
struct InterruptNote {
  char line[1024];
  char marker[4096];
};
InterruptNote g_notes[2];
std::atomic<int> g_note{-1};
std::mutex g_note_mutex;

void write_interrupt_note() {
  const int i = g_note.load();
  if (i < 0) return;
  const InterruptNote& note = g_notes[i];
  (void)!::write(STDERR_FILENO, note.line, std::strlen(note.line));
  if (note.marker[0] != '\0') {
    const int fd = ::open(note.marker, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    if (fd >= 0) {
      (void)!::write(fd, note.line, std::strlen(note.line));
      ::close(fd);
    }
  }
}

// set_interrupt_watch's files, built whole before they are published (and kept
// until exit: a watch is set a few times per process).
struct InterruptWatch {
  int wait_ms = 0;
  std::vector<std::string> said, unless;
};
std::deque<InterruptWatch> g_watches;  // every watch set (the handler may be reading an old one)
std::atomic<const InterruptWatch*> g_watch{nullptr};

// Async-signal-safe: open, read, access, nanosleep, write.
void write_watched_lines() {
  const InterruptWatch* w = g_watch.load();
  if (!w || w->said.empty()) return;
  timespec pause{w->wait_ms / 1000, static_cast<long>(w->wait_ms % 1000) * 1000000L};
  while (::nanosleep(&pause, &pause) != 0 && errno == EINTR) {
  }
  for (std::size_t i = 0; i < w->said.size(); ++i) {
    if (::access(w->unless[i].c_str(), F_OK) == 0) continue;
    const int fd = ::open(w->said[i].c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) continue;
    char text[1024];
    const ssize_t n = ::read(fd, text, sizeof text);
    ::close(fd);
    if (n <= 0) continue;
    const char* end = text + n;
    const char* line = std::find(static_cast<const char*>(text), end, '\n');
    if (line == end) continue;
    ++line;
    const char* stop = std::find(line, end, '\n');
    if (stop == line) continue;
    const char head[] = "hisnegs: ";
    (void)!::write(STDERR_FILENO, head, sizeof head - 1);
    (void)!::write(STDERR_FILENO, line, static_cast<std::size_t>(stop - line));
    (void)!::write(STDERR_FILENO, "\n", 1);
  }
}

extern "C" void remove_temporaries_and_exit(int sig) {
  io::unlink_live_temporaries();
  write_interrupt_note();
  write_watched_lines();
  const char* name = sig == SIGINT ? "SIGINT" : sig == SIGTERM ? "SIGTERM" : "SIGHUP";
  const char head[] = "hisnegs: interrupted by ";
  const char tail[] = "; unfinished outputs removed\n";
  (void)!::write(STDERR_FILENO, head, sizeof head - 1);
  (void)!::write(STDERR_FILENO, name, std::strlen(name));
  (void)!::write(STDERR_FILENO, tail, sizeof tail - 1);
  ::_exit(128 + sig);
}

}  // namespace

void install_interrupt_cleanup() {
  struct sigaction action {};
  action.sa_handler = remove_temporaries_and_exit;
  sigemptyset(&action.sa_mask);
  for (int sig : {SIGINT, SIGTERM, SIGHUP}) ::sigaction(sig, &action, nullptr);
  ::signal(SIGXFSZ, SIG_IGN);
}

void set_interrupt_note(std::string_view line, const fs::path& marker) {
  const std::lock_guard lock(g_note_mutex);
  if (line.empty()) {
    g_note.store(-1);
    return;
  }
  const int i = g_note.load() == 0 ? 1 : 0;  // the slot not in use
  InterruptNote& note = g_notes[i];
  const std::size_t n = std::min(line.size(), sizeof note.line - 2);
  std::memcpy(note.line, line.data(), n);
  note.line[n] = '\n';
  note.line[n + 1] = '\0';
  const std::string m = marker.string();
  const std::size_t k = m.size() < sizeof note.marker ? m.size() : 0;  // a longer path: no marker
  std::memcpy(note.marker, m.data(), k);
  note.marker[k] = '\0';
  g_note.store(i);
}

void set_interrupt_watch(const std::vector<std::pair<fs::path, fs::path>>& files, int wait_ms) {
  if (files.empty()) {
    g_watch.store(nullptr);
    return;
  }
  InterruptWatch w;
  w.wait_ms = std::max(0, wait_ms);
  for (const auto& [said, unless] : files) {
    w.said.push_back(said.string());
    w.unless.push_back(unless.string());
  }
  const std::lock_guard lock(g_note_mutex);
  g_watches.push_back(std::move(w));
  g_watch.store(&g_watches.back());
}

}  // namespace hisnegs::apps
