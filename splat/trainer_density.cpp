// SPDX-License-Identifier: Apache-2.0
// Trainer::densify and Trainer::prune: which Gaussians to split, clone or drop
// (by screen-space gradient and intensity); the operations are gmf/core/density_ops.hpp's.
#include <algorithm>
#include <array>
#include <cmath>
#include <span>

#include "gmf/core/density_ops.hpp"
#include "io/fault_injection.hpp"
#include "splat/trainer.hpp"

namespace hisnegs::splat {

DensifyChange Trainer::densify() {
  const std::size_t K = params_.size() / gmf::kGaussianParamCount;
  std::vector<std::size_t> candidates;
  std::vector<double> mean_grad(K, 0.0);
  for (std::size_t k = 0; k < K; ++k) {
    if (grad_count_[k] == 0) continue;
    mean_grad[k] = grad_accum_[k] / grad_count_[k];
    if (mean_grad[k] >= options_.densify_grad_threshold) candidates.push_back(k);
  }
  std::stable_sort(candidates.begin(), candidates.end(),
                   [&](std::size_t a, std::size_t b) { return mean_grad[a] > mean_grad[b]; });
  DensifyChange change;
  long long room = static_cast<long long>(options_.max_gaussians) - static_cast<long long>(K);
  gmf::GaussianMixture added;
  for (std::size_t k : candidates) {
    if (room <= 0) break;
    const auto row = std::span<float>(params_).subspan(k * gmf::kGaussianParamCount, gmf::kGaussianParamCount);
    std::array<float, gmf::kGaussianParamCount> values;
    std::copy(row.begin(), row.end(), values.begin());
    gmf::GaussianParams g = gmf::from_array(values);
    if (std::exp(static_cast<double>(g.log_scale[gmf::longest_axis(g)])) > options_.densify_scale_threshold) {
      added.push_back(gmf::split_gaussian(g, options_.split_offset, options_.split_scale));
      values = gmf::to_array(g);
      std::copy(values.begin(), values.end(), row.begin());
      adam_.reset(k);  // the parent became a new Gaussian: its moments restart like its twin's
      ++change.split;
    } else {
      added.push_back(g);  // a clone: the original keeps its moments, so the two separate
      ++change.cloned;
    }
    io::fault_point("densify");  // some Gaussians split, the rest not yet
    --room;
  }
  const auto flat = gmf::flat_params(added);
  params_.insert(params_.end(), flat.begin(), flat.end());
  adam_.resize(params_.size() / gmf::kGaussianParamCount);
  resize_state(params_.size() / gmf::kGaussianParamCount);
  return change;
}

Trainer::Pruned Trainer::prune() {
  const std::size_t K = params_.size() / gmf::kGaussianParamCount;
  std::vector<std::uint32_t> kept = gmf::bright_gaussians(params_, options_.prune_intensity);
  Pruned pruned;
  if (volume_) {
    const std::size_t bright = kept.size();
    std::erase_if(kept, [&](std::uint32_t k) {
      return volume_->centre_in_empty_space(params_.data() + gmf::kGaussianParamCount * k);
    });
    pruned.empty = static_cast<int>(bright - kept.size());
  }
  gmf::keep_rows(params_, kept, gmf::kGaussianParamCount);
  adam_.keep(kept);
  gmf::keep_rows(grad_accum_, kept);
  gmf::keep_rows(grad_count_, kept);
  pruned.total = static_cast<int>(K - kept.size());
  return pruned;
}

}  // namespace hisnegs::splat
