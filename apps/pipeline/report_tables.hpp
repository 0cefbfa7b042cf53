// SPDX-License-Identifier: Apache-2.0
// What the reports (`run`'s report.md, `bench report`) share: tables that print
// as Markdown and CSV, the report's standard tables, and a description of the machine.
#pragma once

#include <array>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "gmf/core/gaussian_mixture.hpp"

namespace hisnegs::apps {

// A table of text cells; every row has as many cells as the header.
struct Table {
  std::vector<std::string> header;
  std::vector<std::vector<std::string>> rows;
  void add(std::vector<std::string> row);  // throws std::logic_error on a width mismatch
  [[nodiscard]] std::string markdown() const;
  [[nodiscard]] std::string csv() const;  // cells with , or " quoted
};

// The median of `values` (mean of the middle two for an even count), 0 if empty.
[[nodiscard]] double median(std::vector<double> values);

// "AMD EPYC 7B13 (2 logical CPUs), 23.5 GiB RAM; GPU: none (reason)" for the top of reports.
[[nodiscard]] std::string machine_description();

// The size of a file in bytes, 0 if it does not exist.
[[nodiscard]] double file_bytes(const std::string& path);

// Report Table 10 from per-frame render times (seconds): mean, median, best, worst,
// standard deviation, mean FPS, whether every frame beats 30 FPS.
[[nodiscard]] Table frame_time_table(std::vector<double> seconds);

// Report Table 3 for one or more models: K, memory (K x 11 float32), mean scale per
// axis, intensity range, one column per (label, statistics) pair.
[[nodiscard]] Table gaussian_table(const std::vector<std::pair<std::string, gmf::MixtureStats>>& models);

// Report Table 12: the raw float32 volume against the Gaussian mixture (K x 11
// float32), plus, when given, the sparse grid file and the checkpoint file on disk.
struct MemoryInputs {
  std::array<int, 3> shape_xyz{0, 0, 0};
  std::size_t gaussians = 0;
  std::optional<std::pair<std::string, double>> sparse_file;      // (name, bytes)
  std::optional<std::pair<std::string, double>> checkpoint_file;  // (name, bytes)
};
[[nodiscard]] Table memory_table(const MemoryInputs& in);

}  // namespace hisnegs::apps
