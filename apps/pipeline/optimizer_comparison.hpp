// SPDX-License-Identifier: Apache-2.0
// The optimizer comparison of `compare-optimizers` (config sections volume,
// sparse_grid, gmf) written as a folder: table, curves, summary and plot.
#pragma once

#include <filesystem>
#include <string>

#include "apps/pipeline/fit_stage.hpp"
#include "apps/pipeline/progress.hpp"
#include "gmf/compare.hpp"

namespace hisnegs::apps {

// Every optimizer of `compare` from prepare_fit()'s initialization under the same
// budget (gmf::compare_optimizers): DIR/results.csv, curves.csv, summary.md and
// loss_vs_time.png, rewritten after each optimizer so a stopped comparison keeps
// what it measured. Progress: every 25th iteration and each round's 3D PSNR, then a
// line per optimizer.
gmf::Comparison write_optimizer_comparison(const std::filesystem::path& dir, const std::string& volume,
                                           const FitConfig& config, const gmf::CompareOptions& compare,
                                           const Progress& progress);

// The same on a prepared fit (prepare_fit(); `volume` names it in summary.md), with
// the registered or user-given optimizers of compare.custom too; the files only
// when `dir` is not empty. What the Python module's compare_optimizers runs.
gmf::Comparison compare_prepared(const FitSetup& setup, const std::string& volume, const FitConfig& config,
                                 const gmf::CompareOptions& compare, const std::filesystem::path& dir,
                                 const Progress& progress);

}  // namespace hisnegs::apps
