// SPDX-License-Identifier: Apache-2.0
// What one invocation of run_pipeline did, stage by stage: returned by
// run_pipeline (run_pipeline.hpp) and written into report.md (run_report.hpp).
#pragma once

#include <string>
#include <vector>

namespace hisnegs::apps {

struct StageTiming {
  std::string name;
  double seconds = 0;   // wall time of the stage when it ran (an earlier run's, if reused)
  bool reused = false;  // finished by an earlier invocation
};

struct RunSummary {
  std::vector<StageTiming> stages;
  double seconds = 0;  // wall time of this invocation
};

}  // namespace hisnegs::apps
