// SPDX-License-Identifier: Apache-2.0
// DIR/report.md of a run folder, read back from the folder's own files, so a run
// whose stages were all reused gets the same report as the one that made them.
#pragma once

#include <filesystem>
#include <nlohmann/json.hpp>

#include "apps/pipeline/run_summary.hpp"
#include "splat/backend.hpp"

namespace hisnegs::apps {

// Summary, stage timings, per-view metrics (report Table 8), training curve,
// Gaussian statistics (Table 3), memory and compression (Table 12), orbit frame
// times (Table 10). Throws io::InputError naming a missing or damaged file.
void write_run_report(const std::filesystem::path& dir, const nlohmann::ordered_json& run_state,
                      const RunSummary& summary, splat::Backend backend);

}  // namespace hisnegs::apps
