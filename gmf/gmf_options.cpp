// SPDX-License-Identifier: Apache-2.0
// GmfOptions::validate and the round's mixture model.
#include "gmf/gmf_options.hpp"

#include "io/memory_limit.hpp"

#include <algorithm>
#include <cmath>
#include <string>

namespace hisnegs::gmf {

void GmfOptions::validate() const {
  constexpr const char* s = "gmf";
  io::require_in_range(s, "gaussians", gaussians, 1, 1e7);
  io::require_in_range(s, "max_axis_ratio", max_axis_ratio, 1.5, 1e6);
  io::require_in_range(s, "time_budget_s", time_budget_s, 0.0, 1e9);  // 0: no limit
  io::require_in_range(s, "rounds", rounds, 1, 1000);
  io::require_in_range(s, "iterations_per_round", iterations_per_round, 1, 100000);
  io::require_in_range(s, "max_iterations", max_iterations, 0, 1e9);
  io::require_in_range(s, "stop_loss", stop_loss, 0.0, 1e300);
  io::require_positive(s, "mahalanobis_cutoff", mahalanobis_cutoff);
  io::require_in_range(s, "prune_intensity", prune_intensity, 0.0, 0.999999);
  io::require_in_range(s, "split_scale", split_scale, 1e-6, 0.999999);
  io::require_in_range(s, "split_offset", split_offset, 0.0, 2.0);
  io::require_in_range(s, "densify_fraction", densify_fraction, 1e-9, 1.0);
  io::require_in_range(s, "clone_residual", clone_residual, 1e-9, 1.0 - 1e-9);
  io::require_in_range(s, "clone_floor", clone_floor, 0.0, 1.0 - 1e-9);
  io::require_in_range(s, "background_fraction", background_fraction, 0.0, 1.0);
  io::require_in_range(s, "background_weight", background_weight, 0.0, 1e9);
  io::require_positive(s, "adam_learning_rate", adam_learning_rate);
  io::require_in_range(s, "beta_start", beta_start, 1e-6, 1e4);
  io::require_in_range(s, "beta_end", beta_end, beta_start, 1e4);
  io::require_in_range(s, "beta_growth", beta_growth, 1.0, 1e3);
  io::require_in_range(s, "hard_share", hard_share, 0.0, 0.99);
  io::require_in_range(s, "report_beta", report_beta, 0.0, 1e4);
  const bool logs_at_report_beta = optimizer == Optimizer::kAdam || optimizer == Optimizer::kBrickLm;
  if (report_beta > 0 && aggregation == Aggregation::kSoftmax && !logs_at_report_beta &&
      (beta_start != report_beta || beta_end != report_beta)) {
    io::fail_option(s, "report_beta", std::to_string(report_beta),
                    "only adam and brick-lm log their loss at another β than they solve at");
  }
  io::require_in_range(s, "brick_voxels", brick_voxels, 2, 256);
  if ((brick_voxels & (brick_voxels - 1)) != 0) {
    io::fail_option(s, "brick_voxels", std::to_string(brick_voxels), "must be a power of two");
  }
  io::require_in_range(s, "brick_gaussians", brick_gaussians, 1, 10000);
  io::require_in_range(s, "brick_iterations", brick_iterations, 1, 1000);
  io::require_in_range(s, "outside_voxels", outside_voxels, 0, 8);
  io::require_in_range(s, "stream_brick_voxels", stream_brick_voxels, 0, 65536);
  if (stream_brick_voxels > 0 && stream_brick_voxels < kSmallestStreamBrick) {
    io::fail_option(s, "stream_brick_voxels", std::to_string(stream_brick_voxels),
                    "must be 0 (planned from max_memory) or at least " + std::to_string(kSmallestStreamBrick) +
                        " voxels (--brick-voxels)");
  }
  io::require_in_range(s, "stream_scale_voxels", stream_scale_voxels, 0.5, 64.0);
  io::require_in_range(s, "seam_iterations", seam_iterations, 0, 100000);
  (void)io::parse_memory_size(max_memory, "gmf.max_memory");
  if (frozen > 0 && (optimizer != Optimizer::kAdam || densify)) {
    io::fail_option(s, "optimizer", "frozen Gaussians", "only Adam without density control holds Gaussians fixed");
  }
  if ((optimizer == Optimizer::kCustom) != (custom != nullptr)) {
    io::fail_option(s, "optimizer", custom ? "a custom solver" : "custom",
                    "a custom optimizer needs its solver (gmf/round_solver.hpp), and only it");
  }
  if (sample_jitter) io::require_in_range(s, "sample_jitter", *sample_jitter, 0.0, 1.0);
  if (residual_block_voxels != 1 && residual_block_voxels != 2 && residual_block_voxels != 4 &&
      residual_block_voxels != 8) {
    io::fail_option(s, "residual_block_voxels", std::to_string(residual_block_voxels), "must be 1, 2, 4 or 8");
  }
}

double GmfOptions::largest_scale(double min_voxel, double max_voxel) const {
  const double largest = max_scale_world > 0 ? max_scale_world : std::min(0.5, 32.0 * max_voxel);
  return std::max(0.2 * min_voxel, largest);
}

double GmfOptions::jitter() const { return sample_jitter.value_or(aggregation == Aggregation::kSum ? 0.0 : 1.0); }

MixtureModel GmfOptions::model(int round, bool hard) const {
  MixtureModel m;
  m.aggregation = hard && aggregation == Aggregation::kSoftmax ? Aggregation::kMax : aggregation;
  m.cutoff = mahalanobis_cutoff;
  m.beta = std::min(beta_end, beta_start * std::pow(beta_growth, round));
  return m;
}

bool GmfOptions::hard_round(int round, double seconds) const {
  if (aggregation != Aggregation::kSoftmax || !(hard_share > 0)) return false;
  const bool by_rounds = round >= static_cast<int>(std::ceil((1.0 - hard_share) * rounds));
  return by_rounds || (time_budget_s > 0 && seconds >= (1.0 - hard_share) * time_budget_s);
}

Aggregation GmfOptions::final_aggregation() const {
  return aggregation == Aggregation::kSoftmax && hard_share > 0 ? Aggregation::kMax : aggregation;
}

MixtureModel GmfOptions::report_model(int round, bool hard) const {
  MixtureModel m = model(round, hard);
  if (report_beta > 0 && m.aggregation == Aggregation::kSoftmax) m.beta = report_beta;
  return m;
}

}  // namespace hisnegs::gmf
