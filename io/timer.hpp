// SPDX-License-Identifier: Apache-2.0
// Wall-clock stopwatch for progress lines and timings in metadata. Not a benchmark
// harness (that is Google Benchmark in apps/bench).
#pragma once

#include <chrono>

namespace hisnegs::io {

class Stopwatch {
 public:
  Stopwatch() : start_(Clock::now()), lap_(start_) {}
  // Seconds since construction.
  [[nodiscard]] double elapsed() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }
  // Seconds since the previous lap() (or construction), and starts a new lap.
  double lap() {
    const auto now = Clock::now();
    const double s = std::chrono::duration<double>(now - lap_).count();
    lap_ = now;
    return s;
  }

 private:
  using Clock = std::chrono::steady_clock;
  Clock::time_point start_, lap_;
};

}  // namespace hisnegs::io
