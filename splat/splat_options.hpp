// SPDX-License-Identifier: Apache-2.0
// Options of the rendering and training stages, one struct per config section:
// `camera`, `raymarch`, `splat`, `train` (report Table 1 and Table 4). Only
// definitions, defaults and validation; the code that uses them lives beside.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "io/config.hpp"
#include "splat/splat_math.hpp"

namespace hisnegs::splat {

// The largest soft-MIP β: the renderers are exact in float up to it (β g − M keeps
// its error below 1e-3 there; at 1e9 pixels went negative). Beyond it, the hard
// MIP (its β → ∞ limit) is the exact answer.
inline constexpr double kMaxSoftMipBeta = 1e4;
// The smallest image edge the losses take (the SSIM window, losses.hpp).
inline constexpr int kMinImageEdge = 11;
// The largest image side hisnegs renders (config camera.width/height, cameras.json).
inline constexpr int kMaxImageSide = 16384;

// Pinhole camera and orbit (CONVENTIONS "Cameras").
struct CameraOptions {
  int width = 256;            // image width, pixels, [8, 16384]
  int height = 256;           // image height, pixels, [8, 16384]
  double fov_deg = 50.0;      // horizontal field of view, degrees, (0, 180)
  double near = 0.01;         // near clipping distance, world units, > 0
  double far = 10.0;          // far clipping distance, world units, > near
  double orbit_radius = 2.5;  // orbit camera distance from the origin, world units, > 0
  // `run`'s training views closer than the orbit (users zoom in a viewer): per
  // fraction f of orbit_radius, in [0.3, 1), 32 views at radius f × orbit_radius
  // (splat::close_views) beside the 106 of the training orbit; empty: the orbit
  // alone (the report). The evaluation orbit never changes.
  std::vector<double> close_radii{0.7};
  static constexpr int kCloseViewsPerRadius = 32;

  void validate() const;
  template <class V>
  void visit(V&& v) {
    v("width", width);
    v("height", height);
    v("fov_deg", fov_deg);
    v("near", near);
    v("far", far);
    v("orbit_radius", orbit_radius);
    v("close_radii", close_radii);
  }
};

enum class RaymarchMode { kExact, kReport };

// Ground-truth ray marching (CONVENTIONS "Ground-truth MIP").
struct RaymarchOptions {
  RaymarchMode mode = RaymarchMode::kExact;  // exact | report
  double step_voxels = 0.5;                  // exact mode step, in units of the smallest world voxel size, (0, 4]
  int samples = 200;                         // report mode: number of samples per ray, [2, 100000]
  double t_near = 0.5;                       // report mode: first sample distance, world units, >= 0
  double t_far = 6.0;                        // report mode: last sample distance, world units, > t_near

  void validate() const;
  template <class V>
  void visit(V&& v) {
    v("mode", mode, io::EnumNames<RaymarchMode>{{"exact", RaymarchMode::kExact}, {"report", RaymarchMode::kReport}});
    v("step_voxels", step_voxels);
    v("samples", samples);
    v("t_near", t_near);
    v("t_far", t_far);
  }
};

// Soft/hard-MIP splatting (report Eq. 2-8, §9.3).
struct SplatOptions {
  MipMode mode = MipMode::kSoftmax;     // soft | hard
  double beta = 50.0;                // soft-MIP sharpness β, (0, kMaxSoftMipBeta]
  double mahalanobis_cutoff = 16.0;  // δ: a Gaussian touches pixels with dᵀΣ⁻¹d <= δ, > 0
  double low_pass = 0.0;             // 2D dilation added to Σ_2D diagonal, pixels², >= 0 (report: none)
  // Soft-MIP terms whose softmax weight is below e^-skip_log_weight of the pixel's
  // largest (β a_k < m − skip_log_weight) are skipped by the fast back ends, and
  // counted; 0 = never skip. The error this allows in a pixel is below
  // (number of skipped terms) × e^-skip_log_weight (2e-9 each at 20). [0, 100]
  double skip_log_weight = 20.0;
  // Draw the MIP floor of the background a checkpoint records (gmf::BackgroundModel,
  // splat/background_floor.hpp) under the Gaussians, as the ground truth has it;
  // false (`--background none`): the Gaussians alone, a clean look.
  bool background = true;

  void validate() const;
  template <class V>
  void visit(V&& v) {
    v("mode", mode, io::EnumNames<MipMode>{{"soft", MipMode::kSoftmax}, {"hard", MipMode::kMax}});
    v("beta", beta);
    v("mahalanobis_cutoff", mahalanobis_cutoff);
    v("low_pass", low_pass);
    v("skip_log_weight", skip_log_weight);
    v("background", background);
  }
};

// Stage-2 training (report §6, Tables 1 and 4).
struct TrainOptions {
  int epochs = 2000;         // training epochs, [1, 10^7]
  double lr_initial = 3e-3;  // Adam learning rate at epoch 0, > 0
  double lr_final = 1e-5;    // learning rate at the last epoch (cosine decay), (0, lr_initial]
  // Per-group multipliers of the learning rate (the report uses one rate for all: 1).
  // The means' rate is also multiplied by the scene scale (1 for hisnegs worlds).
  double lr_means = 1.0;           // means, > 0
  double lr_log_scales = 1.0;      // log-scales, > 0
  double lr_rotation = 1.0;        // raw quaternions, > 0
  double lr_intensity = 1.0;       // intensity logits, > 0
  double beta_start = 10.0;        // β at epoch 0, (0, kMaxSoftMipBeta]
  double beta_end = 50.0;          // β after warm-up, [beta_start, kMaxSoftMipBeta]
  int beta_warmup_epochs = 500;    // linear β warm-up length, epochs, [0, 10^7] (may exceed epochs)
  // The share of the epochs that ends on the hard MIP itself, [0, 1): from epoch
  // ceil((1 − hard_share) × epochs) on, views are rendered as the viewer and the
  // ground truth do (the max) and each pixel's gradient goes to its argmax Gaussian
  // (the max's subgradient), and the 3D term uses the max too. At β = 50 a softmax
  // of dim terms is close to their mean, so dim halos that every viewer shows were
  // never trained away (docs/benchmarks.md "The hard MIP"; chosen there: on op3_raw
  // 0.5 gave 45.98 dB, 0.25 45.34 dB, 0 40.34 dB). 0: soft-MIP only.
  double hard_share = 0.5;
  double foreground_weight = 5.0;  // w_fg of the weighted MSE (Eq. 11), >= 1
  double lambda_ssim = 0.2;        // weight of 1 - SSIM (Eq. 12), >= 0
  double lambda_edge = 0.1;        // weight of the Sobel edge loss (Eq. 13), >= 0
  double lambda_intensity = 0.01;  // weight of the histogram KL (Eq. 14), >= 0
  double lambda_scale = 1.0;       // weight of the scale regularizer (Eq. 15), >= 0
  double scale_min = 0.001;        // s_min of Eq. 15, world units, > 0
  double scale_max = 0.5;          // s_max of Eq. 15, world units, > scale_min
  // Largest axis ratio of a Gaussian, kept by a projection after every Adam step
  // (gmf::bound_axis_ratio), as the fit keeps it (gmf.max_axis_ratio). [1.5, 1e6].
  double max_axis_ratio = 16.0;
  int densify_every = 100;         // split/clone period, epochs, >= 1
  int densify_from = 100;          // first epoch of split/clone, >= 0
  int densify_until = 1500;        // last epoch of split/clone, >= densify_from
  // Split/clone a Gaussian whose mean over views of |dL_view/dμ2D| × (pixels per view)
  // reaches this (pixels⁻¹; the gradient of the per-view pixel sum), >= 0.
  double densify_grad_threshold = 0.05;
  double densify_scale_threshold = 0.01;  // largest scale above: split, else clone; world units, > 0
  double split_scale = 0.8;               // Eq. 17: children's scales = split_scale × parent's, (0, 1]
  double split_offset = 0.5;              // Eq. 17: children at μ ± split_offset × s_max (longest axis), >= 0
  int prune_every = 25;                   // prune period, epochs, >= 1
  double prune_intensity = 0.01;          // prune a_k below this, [0, 1)
  int max_gaussians = 100000;             // cap on K during density control, >= 1
  int save_every = 100;                   // checkpoint period, epochs, >= 1
  int views_per_step = 1;                 // mini-batch of views per optimizer step, >= 1
  int crop_size = 0;                      // random square crop edge, pixels (0 = whole image)
  std::uint64_t seed = 0;                 // view shuffling, crops, density control
  // The 3D term (used when training is given the volume, as `run` always is):
  // lambda_3d × the mean squared stage-1 residual (w (f − V))² of the model's own 3D
  // value f on volume_blocks sample blocks drawn afresh each step, added to the loss
  // (0 turns it off). With the volume, pruning also drops Gaussians whose centre is
  // outside the foreground and its band.
  double lambda_3d = 0.1;  // >= 0
  int volume_blocks = 4;   // sample blocks (8^3 voxels) per step, [1, 10^6]
  // After the last epoch, the trained model and the initial one are measured on
  // every training view (hard MIPs after a hard share, else soft at beta_end); when training made the training
  // views worse, `train` writes the initial model as final.ply and says so. False:
  // always the trained model. (Model selection on the training views only.)
  bool keep_better_init = true;

  void validate() const;
  template <class V>
  void visit(V&& v) {
    v("epochs", epochs);
    v("lr_initial", lr_initial);
    v("lr_final", lr_final);
    v("lr_means", lr_means);
    v("lr_log_scales", lr_log_scales);
    v("lr_rotation", lr_rotation);
    v("lr_intensity", lr_intensity);
    v("beta_start", beta_start);
    v("beta_end", beta_end);
    v("beta_warmup_epochs", beta_warmup_epochs);
    v("hard_share", hard_share);
    v("foreground_weight", foreground_weight);
    v("lambda_ssim", lambda_ssim);
    v("lambda_edge", lambda_edge);
    v("lambda_intensity", lambda_intensity);
    v("lambda_scale", lambda_scale);
    v("scale_min", scale_min);
    v("scale_max", scale_max);
    v("max_axis_ratio", max_axis_ratio);
    v("densify_every", densify_every);
    v("densify_from", densify_from);
    v("densify_until", densify_until);
    v("densify_grad_threshold", densify_grad_threshold);
    v("densify_scale_threshold", densify_scale_threshold);
    v("split_scale", split_scale);
    v("split_offset", split_offset);
    v("prune_every", prune_every);
    v("prune_intensity", prune_intensity);
    v("max_gaussians", max_gaussians);
    v("save_every", save_every);
    v("views_per_step", views_per_step);
    v("crop_size", crop_size);
    v("seed", seed);
    v("lambda_3d", lambda_3d);
    v("volume_blocks", volume_blocks);
    v("keep_better_init", keep_better_init);
  }
};

}  // namespace hisnegs::splat
