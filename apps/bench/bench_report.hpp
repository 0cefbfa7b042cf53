// SPDX-License-Identifier: Apache-2.0
// `hisnegs bench report`: the reference report's Tables 7, 9, 10, 11 and 12
// measured in one run on this machine, as Markdown and CSV.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "apps/pipeline/progress.hpp"
#include "splat/backend.hpp"

namespace hisnegs::apps::bench {

struct BenchReportRequest {
  std::filesystem::path dir;     // output folder
  std::filesystem::path volume;  // TIFF stack for the ray marcher and Table 12
  std::string volume_label;      // how the report names it (default: the path)
  std::filesystem::path model;   // checkpoint for Tables 7, 10, 11, 12; empty: synthetic
  int model_gaussians = 50000;   // K of the synthetic model
  splat::Backend backend = splat::Backend::kCpu;
  std::vector<int> sizes{128, 256, 512, 1024};                    // Table 7
  std::vector<int> gaussians{12000, 25000, 37000, 50000, 62000};  // Table 9
  std::vector<float> betas{1, 5, 10, 20, 50, 100, 200, 500};      // Table 11
  int orbit_frames = 72;                                          // Table 10
  int quality_views = 30;                                         // Table 11 images
  int min_frames = 5, max_frames = 60;                            // per timed case
  double seconds_per_case = 3.0;
};

// Writes DIR/report.md and DIR/table{7,9,10,11,12}.csv; a "bench report: ..." line per
// measured row. Throws io::InputError for empty lists or a bad frame range.
void write_bench_report(const BenchReportRequest& request, const Progress& progress);

}  // namespace hisnegs::apps::bench
