// SPDX-License-Identifier: Apache-2.0
// Trainer: the schedule, the epoch loop, one Adam step (loss, gradients, update)
// and evaluation. Density control is in trainer_density.cpp, the state record in
// trainer_state.cpp, checkpoints in training_checkpoint.cpp.
#include "splat/trainer.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>
#include <numeric>
#include <stdexcept>

#include "gmf/core/density_ops.hpp"
#include "gmf/core/psnr.hpp"
#include "io/fault_injection.hpp"
#include "io/hash.hpp"
#include "io/timer.hpp"

namespace hisnegs::splat {

double learning_rate(const TrainOptions& o, int epoch) {
  if (o.epochs <= 1) return o.lr_initial;
  const double t = std::clamp(static_cast<double>(epoch) / (o.epochs - 1), 0.0, 1.0);
  return o.lr_final + 0.5 * (o.lr_initial - o.lr_final) * (1.0 + std::cos(std::numbers::pi * t));
}

double soft_mip_beta(const TrainOptions& o, int epoch) {
  if (o.beta_warmup_epochs <= 0) return o.beta_end;
  const double t = std::min(1.0, static_cast<double>(epoch) / o.beta_warmup_epochs);
  return o.beta_start + (o.beta_end - o.beta_start) * t;
}

bool hard_mip_epoch(const TrainOptions& o, int epoch) {
  return o.hard_share > 0 && epoch >= static_cast<int>(std::ceil((1.0 - o.hard_share) * o.epochs));
}

Trainer::Trainer(const TrainOptions& options, const SplatSettings& splat, TrainingData data, std::vector<float> params,
                 std::unique_ptr<SplatRenderer> renderer, double scene_scale)
    : options_(options),
      splat_(splat),
      data_(std::move(data)),
      params_(std::move(params)),
      renderer_(std::move(renderer)),
      scene_scale_(scene_scale),
      weights_(image_loss_weights(options)),
      rng_(options.seed) {
  options_.validate();
  data_.check();
  if (!renderer_) throw std::invalid_argument("Trainer: no renderer");
  if (splat_.mode != MipMode::kSoftmax) throw std::invalid_argument("Trainer: training needs splat.mode soft");
  if (params_.size() % gmf::kGaussianParamCount != 0) {
    throw std::invalid_argument("Trainer: " + std::to_string(params_.size()) +
                                " parameters are not a whole number of Gaussians");
  }
  if (const std::string bad = gmf::describe_non_finite<float>(params_, "value"); !bad.empty()) {
    throw std::invalid_argument("Trainer: " + bad + " of the initial model is not finite");
  }
  if (!(scene_scale_ > 0) || !std::isfinite(scene_scale_))
    throw std::invalid_argument("Trainer: scene_scale must be > 0");
  const int edge = std::min(data_.intrinsics.width, data_.intrinsics.height);
  if (options_.crop_size > edge) {
    throw std::invalid_argument("Trainer: train.crop_size " + std::to_string(options_.crop_size) +
                                " exceeds the image (" + std::to_string(edge) + " pixels)");
  }
  adam_.resize(params_.size() / gmf::kGaussianParamCount);
  resize_state(params_.size() / gmf::kGaussianParamCount);
}

Trainer::~Trainer() = default;

void Trainer::set_floors(std::vector<std::vector<float>> floors) {
  const std::size_t pixels = static_cast<std::size_t>(data_.intrinsics.width) * data_.intrinsics.height;
  if (!floors.empty() && floors.size() != static_cast<std::size_t>(data_.count())) {
    throw std::invalid_argument("Trainer::set_floors: " + std::to_string(floors.size()) + " floors for " +
                                std::to_string(data_.count()) + " views");
  }
  for (const std::vector<float>& f : floors) {
    if (f.size() != pixels) throw std::invalid_argument("Trainer::set_floors: a floor of the wrong size");
  }
  floors_ = std::move(floors);
}

std::span<const float> Trainer::floor_of(int view) const {
  return floors_.empty() ? std::span<const float>() : std::span<const float>(floors_[static_cast<std::size_t>(view)]);
}

void Trainer::resize_state(std::size_t K) {
  grad_accum_.assign(K, 0.0);
  grad_count_.assign(K, 0);
}

std::vector<std::array<int, 2>> Trainer::draw_crops(std::span<const int> view_indices) {
  std::vector<std::array<int, 2>> crops(view_indices.size(), {0, 0});
  for (std::size_t j = 0; j < view_indices.size(); ++j) {
    const int i = view_indices[j];
    if (i < 0 || i >= data_.count()) throw std::out_of_range("Trainer::step: view index " + std::to_string(i));
    if (options_.crop_size > 0) {
      crops[j][0] = std::uniform_int_distribution<int>(0, data_.intrinsics.width - options_.crop_size)(rng_);
      crops[j][1] = std::uniform_int_distribution<int>(0, data_.intrinsics.height - options_.crop_size)(rng_);
    }
  }
  return crops;
}

void Trainer::add_view_gradient(int view, const std::array<int, 2>& crop, SplatSettings settings, StepSums& sums) {
  const std::size_t K = view_screen_grad_.size();
  Intrinsics intr = data_.intrinsics;
  std::span<const float> target = data_.image(view);
  settings.floor = floor_of(view);
  if (options_.crop_size > 0) {
    // A random crop is the same pinhole camera with its principal point shifted.
    const int c = options_.crop_size;
    const int x0 = crop[0];
    const int y0 = crop[1];
    const auto cut = [&](std::span<const float> image, std::vector<float>& out) {
      out.resize(static_cast<std::size_t>(c) * c);
      for (int r = 0; r < c; ++r) {
        std::copy_n(image.begin() + static_cast<std::ptrdiff_t>(y0 + r) * intr.width + x0, c,
                    out.begin() + static_cast<std::ptrdiff_t>(r) * c);
      }
    };
    cut(target, target_crop_);
    if (!settings.floor.empty()) {
      cut(settings.floor, floor_crop_);
      settings.floor = floor_crop_;
    }
    intr.cx -= x0;
    intr.cy -= y0;
    intr.width = intr.height = c;
    target = target_crop_;
  }
  const std::size_t N = static_cast<std::size_t>(intr.width) * intr.height;
  image_.resize(N);
  dimage_.assign(N, 0.0f);
  renderer_->forward(params_, intr, data_.views[static_cast<std::size_t>(view)], settings, image_);
  const ImageLossTerms terms = combined_image_loss(image_, target, intr.width, intr.height, weights_, dimage_, workspace_);
  std::fill(view_screen_grad_.begin(), view_screen_grad_.end(), 0.0f);
  renderer_->backward(dimage_, grad_, view_screen_grad_);
  for (std::size_t k = 0; k < K; ++k) {
    if (view_screen_grad_[k] > 0.0f) {
      const double g = static_cast<double>(view_screen_grad_[k]) * static_cast<double>(N);
      if (group_) {
        step_accum_[k] += g;
        step_accum_[K + k] += 1.0;
      } else {
        grad_accum_[k] += g;
        ++grad_count_[k];
      }
    }
  }
  sums.loss += terms.total;
  sums.psnr += gmf::psnr(image_, target);
}

void Trainer::add_regularizers(std::size_t views, StepSums& sums) {
  const double reg = options_.lambda_scale * scale_regularizer(std::span<const float>(params_), options_.scale_min,
                                                               options_.scale_max, options_.lambda_scale, grad_);
  sums.loss += static_cast<double>(views) * reg;
  if (volume_ && options_.lambda_3d > 0) {
    volume_batch_.resize(static_cast<std::size_t>(options_.volume_blocks));
    std::uniform_int_distribution<std::uint32_t> pick(0, static_cast<std::uint32_t>(volume_->blocks() - 1));
    for (std::uint32_t& b : volume_batch_) b = pick(rng_);
    sums.loss_3d = volume_->add(params_, volume_batch_, options_.lambda_3d, grad_, hard_mip_epoch(options_, epoch_));
    sums.loss += static_cast<double>(views) * sums.loss_3d;
  }
}

Trainer::StepSums Trainer::train_step(std::span<const int> view_indices) {
  if (view_indices.empty()) throw std::invalid_argument("Trainer::step: no views");
  SplatSettings settings = splat_;
  settings.beta = static_cast<float>(soft_mip_beta(options_, epoch_));
  const bool hard = hard_mip_epoch(options_, epoch_);
  if (hard) {
    settings.mode = MipMode::kMax;
    settings.keep_argmax = true;
  }
  const std::size_t K = params_.size() / gmf::kGaussianParamCount;
  grad_.assign(params_.size(), 0.0f);
  view_screen_grad_.resize(K);
  StepSums sums;
  const std::vector<std::array<int, 2>> crops = draw_crops(view_indices);
  if (group_) step_accum_.assign(2 * K, 0.0);
  for (std::size_t j = 0; j < view_indices.size(); ++j) {
    if (mine(j)) add_view_gradient(view_indices[j], crops[j], settings, sums);
  }
  if (group_) {
    group_->sum(grad_);
    group_->sum(step_accum_);
    std::array<double, 2> step_sums = {sums.loss, sums.psnr};
    group_->sum(step_sums);
    sums.loss = step_sums[0];
    sums.psnr = step_sums[1];
    for (std::size_t k = 0; k < K; ++k) {
      grad_accum_[k] += step_accum_[k];
      grad_count_[k] += static_cast<std::uint32_t>(step_accum_[K + k]);
    }
  }
  const auto B = static_cast<float>(view_indices.size());
  if (view_indices.size() > 1) {
    for (float& g : grad_) g /= B;
  }
  add_regularizers(view_indices.size(), sums);
  if (!std::isfinite(sums.loss)) {
    throw std::runtime_error("training diverged: the loss is not finite in epoch " + std::to_string(epoch_ + 1) +
                             ", step " + std::to_string(adam_.steps() + 1));
  }
  if (const std::string bad = gmf::describe_non_finite<float>(grad_, "gradient"); !bad.empty()) {
    throw std::runtime_error("training diverged in epoch " + std::to_string(epoch_ + 1) + ", step " +
                             std::to_string(adam_.steps() + 1) + ": " + bad + " is not finite");
  }
  adam_update(grad_, learning_rate(options_, epoch_));
  if (const std::string bad = gmf::describe_non_finite<float>(params_, "value"); !bad.empty()) {
    throw std::runtime_error("training diverged in epoch " + std::to_string(epoch_ + 1) + ", step " +
                             std::to_string(adam_.steps()) + ": the update made " + bad + " not finite");
  }
  return sums;
}

double Trainer::step(std::span<const int> view_indices) {
  return train_step(view_indices).loss / static_cast<double>(view_indices.size());
}

void Trainer::adam_update(std::span<const float> grad, double lr) {
  const gmf::GroupRates rates = {lr * options_.lr_means * scene_scale_, lr * options_.lr_log_scales,
                                 lr * options_.lr_rotation, lr * options_.lr_intensity};
  adam_.step(params_, grad, rates);
  (void)gmf::bound_axis_ratio(std::span<float>(params_), options_.max_axis_ratio);
}

Trainer::Evaluation Trainer::evaluate() { return evaluate(params_, soft_mip_beta(options_, epoch_)); }

Trainer::Evaluation Trainer::evaluate(std::span<const float> params, double beta, MipMode mode) {
  if (params.size() % gmf::kGaussianParamCount != 0) {
    throw std::invalid_argument("Trainer::evaluate: params is not a whole number of Gaussians");
  }
  SplatSettings settings = splat_;
  settings.beta = static_cast<float>(beta);
  settings.mode = mode;
  const Intrinsics& intr = data_.intrinsics;
  image_.resize(static_cast<std::size_t>(intr.width) * intr.height);
  Evaluation e;
  const double reg = options_.lambda_scale *
                     scale_regularizer(params, options_.scale_min, options_.scale_max, 0.0, std::span<float>());
  for (int i = 0; i < data_.count(); ++i) {
    if (!mine(static_cast<std::size_t>(i))) continue;
    settings.floor = floor_of(i);
    renderer_->forward(params, intr, data_.views[static_cast<std::size_t>(i)], settings, image_);
    e.loss +=
        combined_image_loss(image_, data_.image(i), intr.width, intr.height, weights_, std::span<float>(), workspace_)
            .total +
        reg;
    e.psnr += gmf::psnr(image_, data_.image(i));
  }
  if (group_) {
    std::array<double, 2> both = {e.loss, e.psnr};
    group_->sum(both);
    e.loss = both[0];
    e.psnr = both[1];
  }
  e.loss /= data_.count();
  e.psnr /= data_.count();
  return e;
}

void Trainer::check_members_agree() const {
  // Member r's hash h_r of the parameters (the state record's, io::fnv1a64), summed in
  // two 32-bit halves (exact in a double): each sum equals n × the member's own half on
  // every member only when all members' halves are equal.
  const std::uint64_t h = io::fnv1a64(params_.data(), params_.size() * sizeof(float));
  const std::array<double, 3> own = {static_cast<double>(h & 0xffffffffu), static_cast<double>(h >> 32),
                                     static_cast<double>(params_.size())};
  std::array<double, 3> sums = own;
  group_->sum(sums);
  const double n = group_->size();
  if (sums[0] != n * own[0] || sums[1] != n * own[1] || sums[2] != n * own[2]) {
    throw std::runtime_error("training: the " + std::to_string(group_->size()) +
                             " ranks' models differ after epoch " + std::to_string(epoch_) +
                             " (a step that is not deterministic on every rank)");
  }
}

EpochReport Trainer::run_epoch() {
  if (finished()) throw std::logic_error("Trainer::run_epoch: all epochs are done");
  io::Stopwatch watch;
  EpochReport report;
  report.lr = learning_rate(options_, epoch_);
  report.beta = hard_mip_epoch(options_, epoch_) ? std::numeric_limits<double>::infinity()
                                                 : soft_mip_beta(options_, epoch_);
  std::vector<int> order(static_cast<std::size_t>(data_.count()));
  std::iota(order.begin(), order.end(), 0);
  std::shuffle(order.begin(), order.end(), rng_);
  const std::size_t B = static_cast<std::size_t>(options_.views_per_step);
  int steps = 0;
  for (std::size_t start = 0; start < order.size(); start += B) {
    const std::size_t n = std::min(B, order.size() - start);
    io::fault_point("train_step");
    const StepSums sums = train_step(std::span<const int>(order).subspan(start, n));
    report.loss += sums.loss;
    report.psnr += sums.psnr;
    report.loss_3d += sums.loss_3d;
    ++steps;
  }
  report.loss /= static_cast<double>(order.size());
  report.psnr /= static_cast<double>(order.size());
  report.loss_3d /= static_cast<double>(steps);
  ++epoch_;
  report.epoch = epoch_;
  if (epoch_ >= options_.densify_from && epoch_ <= options_.densify_until && epoch_ % options_.densify_every == 0) {
    const DensifyChange change = densify();
    report.split = change.split;
    report.cloned = change.cloned;
  }
  if (epoch_ % options_.prune_every == 0) {
    const Pruned pruned = prune();
    report.pruned = pruned.total;
    report.pruned_empty = pruned.empty;
  }
  if (group_) check_members_agree();
  report.gaussians = gaussians();
  report.seconds = watch.elapsed();
  return report;
}

}  // namespace hisnegs::splat
