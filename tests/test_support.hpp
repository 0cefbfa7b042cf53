// SPDX-License-Identifier: Apache-2.0
// Shared helpers for the hisnegs tests: per-test scratch folders, running the
// hisnegs executable, locating ../shared/data. No assertions of their own.
#pragma once

#include <algorithm>
#include <cmath>
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

// Sets an environment variable for one scope and restores what was there (or its
// absence) when destroyed, also when an assertion leaves the test early.
class ScopedEnv {
 public:
  ScopedEnv(const char* name, const char* value);
  ~ScopedEnv();
  ScopedEnv(const ScopedEnv&) = delete;
  ScopedEnv& operator=(const ScopedEnv&) = delete;

 private:
  std::string name_;
  std::optional<std::string> previous_;
};

struct CommandResult {
  int exit_code = -1;  // the process exit status; 128+N when killed by signal N
  std::string out;     // stdout
  std::string err;     // stderr
};

// The hisnegs executable of this build and the source tree (configs/): the paths
// CMake compiled in, or $HISNEGS_TEST_EXE / $HISNEGS_TEST_SOURCE_DIR when set (the
// device bundle, scripts/device-bundle.sh, runs the tests away from the build).
std::filesystem::path hisnegs_exe();
std::filesystem::path source_dir();

// Runs the hisnegs executable of this build with `args` (no shell quoting needed).
CommandResult run_hisnegs(const std::vector<std::string>& args);

// ../shared/data/NAME ($HISNEGS_TEST_SHARED_DATA/NAME when set) if it exists
// (tests on real data skip otherwise).
std::optional<std::filesystem::path> shared_data(const std::string& name);

// The whole file at `path` as bytes ("" when it cannot be read).
std::string read_bytes(const std::filesystem::path& path);

// Data rows of a CSV file (its lines less the header; -1 when it cannot be read).
int csv_data_rows(const std::filesystem::path& path);

struct ShellResult {
  int status = -1;  // pclose's wait status
  std::string out;  // stdout and stderr together
};

// Runs `command` through /bin/sh (the caller quotes its arguments: shell_quoted).
ShellResult run_shell(const std::string& command);

// `path` in single quotes for /bin/sh (scratch paths hold no single quote).
std::string shell_quoted(const std::filesystem::path& path);

// Writes `text` to `path` (test fixtures).
void write_text(const std::filesystem::path& path, const std::string& text);

// Number of lines in `text` ignoring one trailing newline.
int count_lines(const std::string& text);

// Derivative of f at x by Ridders' method: central differences at steps h0,
// h0/1.4, h0/1.4², ... extrapolated to h -> 0 (Richardson tableau), stopping
// when the extrapolation stops improving. Accurate to ~1e-10 relative where a
// single central difference is limited to ~1e-6 by round-off. `h0` should be
// about a tenth of the scale on which f changes. *error gets the estimate.
template <class F>
double ridders_derivative(F&& f, double x, double h0, double* error = nullptr) {
  constexpr int kMax = 12;
  constexpr double kCon = 1.4, kCon2 = kCon * kCon;
  double a[kMax][kMax];
  double h = h0, best = 0, err = 1e300;
  a[0][0] = (f(x + h) - f(x - h)) / (2 * h);
  best = a[0][0];
  for (int i = 1; i < kMax; ++i) {
    h /= kCon;
    a[0][i] = (f(x + h) - f(x - h)) / (2 * h);
    double fac = kCon2;
    for (int j = 1; j <= i; ++j) {
      a[j][i] = (a[j - 1][i] * fac - a[j - 1][i - 1]) / (fac - 1);
      fac *= kCon2;
      const double e = std::max(std::abs(a[j][i] - a[j - 1][i]), std::abs(a[j][i] - a[j - 1][i - 1]));
      if (e <= err) {
        err = e;
        best = a[j][i];
      }
    }
    if (std::abs(a[i][i] - a[i - 1][i - 1]) >= 2 * err) break;
  }
  if (error) *error = err;
  return best;
}

}  // namespace hisnegs::testing
