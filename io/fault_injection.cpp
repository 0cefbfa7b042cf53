// SPDX-License-Identifier: Apache-2.0
// HISNEGS_FAULT=NAME:N parsing (once) and the SIGKILL at the N-th arrival.
#include "io/fault_injection.hpp"

#include <csignal>
#include <cstdlib>
#include <cstring>
#include <string>

#include <atomic>
#include <mutex>

namespace hisnegs::io {
namespace {

struct Fault {
  std::string name;  // empty: no fault armed
  long at = 0;
  int signal = SIGKILL;
  std::atomic<long> seen{0};
};

Fault& armed_fault() {
  static Fault fault;
  static std::once_flag once;
  std::call_once(once, [] {
    const char* env = std::getenv("HISNEGS_FAULT");
    if (!env) return;
    const char* colon = std::strchr(env, ':');
    if (!colon) return;
    char* end = nullptr;
    const long at = std::strtol(colon + 1, &end, 10);
    if (end == colon + 1 || at < 1) return;
    if (std::strcmp(end, ":INT") == 0) {
      fault.signal = SIGINT;
    } else if (std::strcmp(end, ":TERM") == 0) {
      fault.signal = SIGTERM;
    } else if (*end != '\0') {
      return;
    }
    fault.name.assign(env, colon);
    fault.at = at;
  });
  return fault;
}

}  // namespace

void fault_point(const char* name) {
  Fault& f = armed_fault();
  if (f.name.empty() || f.name != name) return;
  if (f.seen.fetch_add(1) + 1 == f.at) std::raise(f.signal);
}

}  // namespace hisnegs::io
