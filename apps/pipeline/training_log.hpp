// SPDX-License-Identifier: Apache-2.0
// The files a training run keeps besides its checkpoints: RUN/log.csv (one row per
// epoch, read back when a run resumes) and the training-curve plot.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "io/png.hpp"

namespace hisnegs::apps {

struct TrainingLogRow {
  int epoch = 0;
  double seconds = 0;  // training wall time up to the end of this epoch, earlier sessions included
  double loss = 0, psnr = 0;
  int gaussians = 0;
  double beta = 0, lr = 0;
};

// The CSV text of `rows` with its header "epoch,seconds,loss,psnr,K,beta,lr".
[[nodiscard]] std::string training_log_csv(const std::vector<TrainingLogRow>& rows);

// The rows of an earlier log up to epoch `last` (what a resumed run continues); none
// if the file does not exist. Throws io::InputError naming the file on a foreign
// header or a malformed line.
[[nodiscard]] std::vector<TrainingLogRow> read_training_log(const std::filesystem::path& path, int last);

// Loss (log scale) above PSNR, both against the epoch.
[[nodiscard]] io::Image8 training_curve(const std::vector<TrainingLogRow>& rows);

}  // namespace hisnegs::apps
