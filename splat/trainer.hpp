// SPDX-License-Identifier: Apache-2.0
// Stage-2 MIP-splatting training (report §6): Adam with per-group learning rates,
// cosine lr decay and β warm-up (Table 4), the Eq. 16 loss, density control (§6.4,
// Eq. 17) and its resumable state. Not the losses (losses.hpp), the renderer, the
// data (training_data.hpp) nor the checkpoint files (training_checkpoint.hpp).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <random>
#include <span>
#include <string>
#include <vector>

#include "gmf/core/adam.hpp"
#include "splat/camera.hpp"
#include "splat/losses.hpp"
#include "splat/splat_options.hpp"
#include "splat/splat_renderer.hpp"
#include "splat/training_data.hpp"
#include "splat/volume_term.hpp"

namespace hisnegs::splat {

// Learning rate of 0-based epoch `epoch` (Table 4): cosine decay
// lr_final + ½ (lr_initial − lr_final)(1 + cos(π e / (epochs − 1))), so epoch 0 trains
// at lr_initial and the last at lr_final (lr_initial when epochs = 1). Constant within an epoch.
[[nodiscard]] double learning_rate(const TrainOptions& options, int epoch);
// Soft-MIP β of 0-based epoch `epoch` (Table 4): beta_start + (beta_end − beta_start)
// × min(1, e / beta_warmup_epochs), beta_end when beta_warmup_epochs = 0.
[[nodiscard]] double soft_mip_beta(const TrainOptions& options, int epoch);
// Whether 0-based epoch `epoch` trains on the hard MIP (train.hard_share): from
// ceil((1 − hard_share) × epochs) on.
[[nodiscard]] bool hard_mip_epoch(const TrainOptions& options, int epoch);

// What one epoch did (means over the training views seen in it).
struct EpochReport {
  int epoch = 0;                          // 1-based number of the epoch just finished
  double loss = 0;                        // mean per-view loss (Eq. 16 image terms + L_reg + the 3D term of its step)
  double loss_3d = 0;                     // mean per-step 3D term (0 without a volume)
  double psnr = 0;                        // mean per-view PSNR, dB (of the crop when crop_size > 0)
  double beta = 0;                        // β it was trained at (+∞: the hard MIP, train.hard_share)
  double lr = 0;                          // base learning rate it was trained at
  double seconds = 0;                     // wall time of the epoch incl. density control
  int gaussians = 0;                      // K after density control
  int split = 0, cloned = 0, pruned = 0;  // density control at its end
  int pruned_empty = 0;                   // of `pruned`: centre in empty space
};

struct DensifyChange {
  int split = 0;   // Gaussians replaced by two children (Eq. 17)
  int cloned = 0;  // small Gaussians duplicated
};

// The processes a Trainer shares its steps with: data parallel over the views of
// each step (the MPI ranks of apps/pipeline/distributed.hpp). Alone: none.
class StepGroup {
 public:
  virtual ~StepGroup() = default;
  [[nodiscard]] virtual int rank() const = 0;
  [[nodiscard]] virtual int size() const = 0;
  // values[i] = the sum of values[i] over the members, in a fixed order, with the same
  // bits on every member.
  virtual void sum(std::span<float> values) const = 0;
  virtual void sum(std::span<double> values) const = 0;
};

// Trains the K Gaussians of `params` (11 K floats, gmf::GaussianParam order) on `data`.
//
// Adam (β1 0.9, β2 0.999, ε 1e-15: the loss is a per-pixel mean, so its gradients are
// small and a larger ε would damp them) with one base rate lr(e) per epoch; group g
// of parameter uses lr(e) × lr_g: lr_means × scene_scale for the means (so means move
// in proportion to the scene: hisnegs worlds are [−a, a] with max a = 1, scene_scale
// 1), lr_log_scales, lr_rotation (the raw quaternion; the renderer normalizes it),
// lr_intensity (the logit). An epoch visits every view once in an order shuffled by
// the seeded std::mt19937_64; each Adam step averages the gradients of
// views_per_step views (the last step of an epoch may hold fewer) and adds the scale
// regularizer (Eq. 15, summed over Gaussians as the report writes it, weight
// lambda_scale) once. After epoch n (1-based) it splits/clones when
// densify_from <= n <= densify_until and n % densify_every == 0, then prunes when
// n % prune_every == 0. Deterministic on the CPU back end.
class Trainer {
 public:
  // `renderer` must be non-null; `splat` gives mode (must be soft), cutoff, low-pass and
  // skip threshold (β comes from the schedule). Throws std::invalid_argument for a
  // params size that is not a whole number of Gaussians, invalid data, or options that fail validate().
  Trainer(const TrainOptions& options, const SplatSettings& splat, TrainingData data, std::vector<float> params,
          std::unique_ptr<SplatRenderer> renderer, double scene_scale = 1.0);
  ~Trainer();
  Trainer(const Trainer&) = delete;
  Trainer& operator=(const Trainer&) = delete;
  Trainer(Trainer&&) noexcept = default;
  Trainer& operator=(Trainer&&) noexcept = default;

  // Trains against the volume as well (see TrainOptions::lambda_3d): from the next
  // step on, each step adds the term on volume_blocks blocks drawn with the trainer's
  // RNG, and prune() also removes Gaussians whose centre `term` says is in empty space.
  void attach_volume(std::shared_ptr<const VolumeTerm> term) { volume_ = std::move(term); }
  // Renders every view over its background floor (one per training view, each the
  // image size: splat/background_floor.hpp), in the steps and in evaluate(), so the
  // loss compares what the ground truth shows: the Gaussians and the noise's MIP.
  // Empty: none. Throws std::invalid_argument for a count or size that does not fit.
  void set_floors(std::vector<std::vector<float>> floors);
  // Shares every step with the members of `group`, each running an identical Trainer
  // (same options, data, parameters and state): member r renders and differentiates
  // the step's views at positions r, r + n, ... (n members), the gradients, losses and
  // density statistics are summed over the group (StepGroup::sum), and every member
  // takes the same Adam step, so the models stay identical (checked after every
  // epoch: a std::runtime_error names the epoch where they differ). evaluate() shares
  // its views the same way. The random crops and the 3D term's blocks are drawn by
  // every member alike; the 3D term is computed by each (not shared). With
  // views_per_step < n, members past the step's views wait.
  void share_steps(std::shared_ptr<const StepGroup> group) { group_ = std::move(group); }
  [[nodiscard]] bool has_volume() const { return volume_ != nullptr; }

  // Runs epoch epoch()+1 and its density control. Precondition: !finished().
  EpochReport run_epoch();
  [[nodiscard]] bool finished() const { return epoch_ >= options_.epochs; }
  // Epochs completed (0 at the start).
  [[nodiscard]] int epoch() const { return epoch_; }
  // Adam steps taken.
  [[nodiscard]] std::int64_t step_count() const { return adam_.steps(); }
  // Whether the epoch just completed is a checkpoint epoch (epoch() % save_every == 0).
  [[nodiscard]] bool checkpoint_due() const { return epoch_ > 0 && epoch_ % options_.save_every == 0; }

  // One Adam step on the views `view_indices` (indices into data) at the current
  // epoch's lr and β; accumulates density statistics. Returns the mean per-view loss.
  double step(std::span<const int> view_indices);
  // Mean loss and PSNR over all training views (whole images) at the current epoch's β,
  // without changing anything but the renderer's scratch.
  struct Evaluation {
    double loss = 0;
    double psnr = 0;
  };
  [[nodiscard]] Evaluation evaluate();
  // The same for other parameters (any whole number of Gaussians) at soft-MIP `beta`,
  // or their hard MIP.
  [[nodiscard]] Evaluation evaluate(std::span<const float> params, double beta, MipMode mode = MipMode::kSoftmax);

  // Density control now (what run_epoch does on schedule). densify(): every Gaussian
  // seen in at least one view whose mean screen-gradient statistic (see
  // grad_accum()) is >= densify_grad_threshold, largest first, while K < max_gaussians:
  // if its largest scale exceeds densify_scale_threshold it is split (Eq. 17: it and
  // an appended twin at μ ± split_offset s_max along its longest axis, scales ×
  // split_scale, same intensity — a MIP takes the max, so intensity is not shared),
  // else cloned (an identical copy appended; the original keeps its moments, so the
  // two separate). Children of a split and clones start with zero Adam moments.
  // Resets the statistics. prune(): removes a_k < prune_intensity and, with a volume
  // attached, Gaussians whose centre is in empty space, compacting every per-Gaussian
  // array in order. Returns the numbers removed (all, and of them for empty space).
  DensifyChange densify();
  struct Pruned {
    int total = 0;
    int empty = 0;
  };
  Pruned prune();

  [[nodiscard]] int gaussians() const { return static_cast<int>(params_.size() / gmf::kGaussianParamCount); }
  [[nodiscard]] std::span<const float> params() const { return params_; }
  // Adam first/second moments, 11 K each, aligned with params().
  [[nodiscard]] std::span<const float> adam_m() const { return adam_.m(); }
  [[nodiscard]] std::span<const float> adam_v() const { return adam_.v(); }
  // Density statistics since the last densify (K each): the sum over views of
  // |∂L_view/∂μ2D| × (pixels of the view) — the gradient of the per-view pixel SUM, so
  // the threshold does not depend on the image size — and the number of views in
  // which the Gaussian got a non-zero screen gradient.
  [[nodiscard]] std::span<const double> grad_accum() const { return grad_accum_; }
  [[nodiscard]] std::span<const std::uint32_t> grad_count() const { return grad_count_; }
  [[nodiscard]] const TrainOptions& options() const { return options_; }
  [[nodiscard]] const TrainingData& data() const { return data_; }

  // The complete optimizer state besides the parameters (moments, step, epoch, RNG,
  // density statistics, options, a hash of the parameters) as bytes, and its inverse.
  // restore_state() takes the parameters the state belongs to and throws io::InputError
  // naming `source` when the bytes are not a state file, the parameters do not match
  // its hash or size, or it was written with different options (only `epochs` may differ).
  [[nodiscard]] std::string serialize_state() const;
  void restore_state(std::string_view bytes, std::vector<float> params, const std::string& source);

 private:
  struct StepSums {
    double loss = 0;     // Σ over the step's views of their loss
    double psnr = 0;     // Σ over the step's views of their PSNR
    double loss_3d = 0;  // the step's 3D term
  };
  StepSums train_step(std::span<const int> view_indices);
  // Each view's random crop origin (all members draw all, to keep their generators in step).
  std::vector<std::array<int, 2>> draw_crops(std::span<const int> view_indices);
  // Renders view `view` (cropped at `crop` when cropping), adds its gradient to grad_
  // and its density statistics, and its loss and PSNR to `sums`.
  void add_view_gradient(int view, const std::array<int, 2>& crop, SplatSettings settings, StepSums& sums);
  // Adds the scale regularizer and the 3D term (over a batch of `views`) to grad_ and `sums`.
  void add_regularizers(std::size_t views, StepSums& sums);
  // Whether this member renders the view at `position` of a step (always alone).
  [[nodiscard]] bool mine(std::size_t position) const {
    return !group_ || static_cast<int>(position % static_cast<std::size_t>(group_->size())) == group_->rank();
  }
  // After an epoch in a group: throws when the members' parameters differ.
  void check_members_agree() const;
  void adam_update(std::span<const float> grad, double lr);
  void resize_state(std::size_t K);

  TrainOptions options_;
  SplatSettings splat_;
  TrainingData data_;
  std::vector<float> params_;
  std::unique_ptr<SplatRenderer> renderer_;
  double scene_scale_ = 1.0;
  ImageLossWeights weights_;
  std::shared_ptr<const VolumeTerm> volume_;
  std::shared_ptr<const StepGroup> group_;
  std::vector<double> step_accum_;  // in a group: this step's density statistics, summed before adding
  std::vector<std::uint32_t> volume_batch_;

  gmf::Adam<float> adam_{gmf::AdamOptions{.epsilon = 1e-15}};
  std::vector<double> grad_accum_;
  std::vector<std::uint32_t> grad_count_;
  int epoch_ = 0;
  std::mt19937_64 rng_;

  // Scratch reused by every step.
  std::vector<float> grad_, image_, dimage_, target_crop_, floor_crop_, view_screen_grad_;
  std::vector<std::vector<float>> floors_;  // per training view, or none
  [[nodiscard]] std::span<const float> floor_of(int view) const;
  LossWorkspace workspace_;
};

}  // namespace hisnegs::splat
