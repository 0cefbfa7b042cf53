// SPDX-License-Identifier: Apache-2.0
// validate() of the splat-layer option structs.
#include "splat/splat_options.hpp"

#include "io/error.hpp"

namespace hisnegs::splat {

void CameraOptions::validate() const {
  constexpr const char* s = "camera";
  io::require_in_range(s, "width", width, 8, kMaxImageSide);
  io::require_in_range(s, "height", height, 8, kMaxImageSide);
  io::require_in_range(s, "fov_deg", fov_deg, 1e-3, 179.999);
  io::require_positive(s, "near", near);
  if (!(far > near)) io::fail_option(s, "far", std::to_string(far), "must be greater than camera.near");
  io::require_positive(s, "orbit_radius", orbit_radius);
  std::string radii = "[";
  for (const double f : close_radii) radii += (radii.size() > 1 ? ", " : "") + io::number_text(f);
  radii += "]";
  if (close_radii.size() > 8) io::fail_option(s, "close_radii", radii, "at most 8 radii");
  for (const double f : close_radii) {
    if (!(f >= 0.3 && f < 1.0)) {
      io::fail_option(s, "close_radii", radii, "each must be a fraction of camera.orbit_radius in [0.3, 1)");
    }
  }
}

void RaymarchOptions::validate() const {
  constexpr const char* s = "raymarch";
  io::require_in_range(s, "step_voxels", step_voxels, 1e-6, 4.0);
  io::require_in_range(s, "samples", samples, 2, 100000);
  io::require_in_range(s, "t_near", t_near, 0.0, 1e6);
  if (!(t_far > t_near)) io::fail_option(s, "t_far", std::to_string(t_far), "must be greater than raymarch.t_near");
}

namespace {
// β in (lower, kMaxSoftMipBeta] (lower = 0: any positive β), one line naming it.
void require_soft_mip_beta(const char* section, const char* name, double beta, double lower) {
  if (!(beta > 0) || !(beta <= kMaxSoftMipBeta) || beta < lower) {
    io::fail_option(section, name, io::number_text(beta),
                    std::string("must be in (0, ") + io::number_text(kMaxSoftMipBeta) + "]" +
                        (lower > 0 ? " and at least " + std::string(section) + ".beta_start (" +
                                         io::number_text(lower) + ")"
                                   : std::string()) +
                        "; for the exact maximum use the hard MIP (splat.mode hard, --mode hard)");
  }
}
}  // namespace

void SplatOptions::validate() const {
  constexpr const char* s = "splat";
  require_soft_mip_beta(s, "beta", beta, 0.0);
  io::require_positive(s, "mahalanobis_cutoff", mahalanobis_cutoff);
  io::require_in_range(s, "low_pass", low_pass, 0.0, 100.0);
  io::require_in_range(s, "skip_log_weight", skip_log_weight, 0.0, 100.0);
}

void TrainOptions::validate() const {
  constexpr const char* s = "train";
  io::require_in_range(s, "epochs", epochs, 1, 1e7);
  io::require_in_range(s, "max_axis_ratio", max_axis_ratio, 1.5, 1e6);
  io::require_positive(s, "lr_initial", lr_initial);
  io::require_in_range(s, "lr_final", lr_final, 1e-300, lr_initial);
  for (auto [name, value] : {std::pair{"lr_means", lr_means}, std::pair{"lr_log_scales", lr_log_scales},
                             std::pair{"lr_rotation", lr_rotation}, std::pair{"lr_intensity", lr_intensity}}) {
    io::require_positive(s, name, value);
  }
  require_soft_mip_beta(s, "beta_start", beta_start, 0.0);
  require_soft_mip_beta(s, "beta_end", beta_end, beta_start);
  // A warm-up longer than the run is allowed (β then never reaches beta_end), so
  // `--epochs` can shorten a run without editing the schedule.
  io::require_in_range(s, "beta_warmup_epochs", beta_warmup_epochs, 0, 1e7);
  io::require_in_range(s, "hard_share", hard_share, 0.0, 0.99);
  io::require_in_range(s, "foreground_weight", foreground_weight, 1.0, 1e6);
  for (auto [name, value] :
       {std::pair{"lambda_ssim", lambda_ssim}, std::pair{"lambda_edge", lambda_edge},
        std::pair{"lambda_intensity", lambda_intensity}, std::pair{"lambda_scale", lambda_scale}}) {
    io::require_in_range(s, name, value, 0.0, 1e6);
  }
  io::require_positive(s, "scale_min", scale_min);
  if (!(scale_max > scale_min))
    io::fail_option(s, "scale_max", std::to_string(scale_max), "must exceed train.scale_min");
  io::require_in_range(s, "densify_every", densify_every, 1, 1e9);
  io::require_in_range(s, "densify_from", densify_from, 0, 1e9);
  io::require_in_range(s, "densify_until", densify_until, densify_from, 1e9);
  io::require_in_range(s, "densify_grad_threshold", densify_grad_threshold, 0.0, 1e30);
  io::require_positive(s, "densify_scale_threshold", densify_scale_threshold);
  io::require_in_range(s, "split_scale", split_scale, 1e-6, 1.0);
  io::require_in_range(s, "split_offset", split_offset, 0.0, 1e3);
  io::require_in_range(s, "prune_every", prune_every, 1, 1e9);
  io::require_in_range(s, "prune_intensity", prune_intensity, 0.0, 0.999999);
  io::require_in_range(s, "max_gaussians", max_gaussians, 1, 1e8);
  io::require_in_range(s, "save_every", save_every, 1, 1e9);
  io::require_in_range(s, "views_per_step", views_per_step, 1, 1e6);
  io::require_in_range(s, "crop_size", crop_size, 0, 16384);
  if (crop_size != 0 && crop_size < kMinImageEdge) {
    io::fail_option(s, "crop_size", std::to_string(crop_size),
                    "must be 0 (whole images) or at least " + std::to_string(kMinImageEdge) +
                        " (the SSIM window)");
  }
  io::require_in_range(s, "lambda_3d", lambda_3d, 0.0, 1e6);
  io::require_in_range(s, "volume_blocks", volume_blocks, 1, 1e6);
}

}  // namespace hisnegs::splat
