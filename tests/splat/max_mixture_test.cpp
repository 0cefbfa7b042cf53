// SPDX-License-Identifier: Apache-2.0
// Why stage 1 fits a max-mixture: for f_max(x) = max_k a_k G_k(x), the MIP along
// a ray is the max over k of each Gaussian's peak on that ray, which is what the
// hard-MIP splat draws. Checked end to end: the ray-marched MIP of the rasterized
// f_max (softmax at a β where it equals the max to 1e-4) against the hard-MIP
// splat of the same Gaussians, from a far, narrow (orthographic-like) camera, for
// overlapping Gaussians where the MIP of the sum would differ.
#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "gmf/core/psnr.hpp"
#include "gmf/core/rasterize.hpp"
#include "splat/raymarch.hpp"
#include "splat/splat_renderer.hpp"

namespace hisnegs::splat {
namespace {

// 12 pairs of Gaussians, each pair overlapping (centres 1.5-3 voxels apart), σ
// 2.5-4 voxels, in a 64 × 64 × 32 volume.
gmf::GaussianMixture overlapping_pairs(const io::WorldFrame& frame, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> n(0, 1);
  const double voxel = frame.voxel_size().x();
  gmf::GaussianMixture m;
  for (int pair = 0; pair < 12; ++pair) {
    const Eigen::Vector3d c = frame.world_from_index(Eigen::Vector3d(14 + 36 * u(rng), 14 + 36 * u(rng), 10 + 12 * u(rng)));
    for (int i = 0; i < 2; ++i) {
      gmf::GaussianParams g;
      const Eigen::Vector3d offset = Eigen::Vector3d(n(rng), n(rng), n(rng)).normalized() * (1.5 + 1.5 * u(rng)) * voxel;
      const Eigen::Vector3d p = i == 0 ? c : Eigen::Vector3d(c + offset);
      for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(p[a]);
      for (int a = 0; a < 3; ++a) g.log_scale[a] = static_cast<float>(std::log((2.5 + 1.5 * u(rng)) * voxel));
      Eigen::Vector4d q(n(rng), n(rng), n(rng), n(rng));
      q.normalize();
      g.rotation = {static_cast<float>(q[0]), static_cast<float>(q[1]), static_cast<float>(q[2]),
                    static_cast<float>(q[3])};
      const double a = 0.3 + 0.6 * u(rng);
      g.intensity_logit = static_cast<float>(std::log(a / (1 - a)));
      m.push_back(g);
    }
  }
  return m;
}

TEST(MaxMixture, HardMipSplatEqualsTheRayMarchedMipOfTheMaxMixture) {
  const int nx = 64, ny = 64, nz = 32;
  const io::WorldFrame frame(nx, ny, nz, Eigen::Vector3d(1.0, 1.0, 0.5));
  const gmf::GaussianMixture mixture = overlapping_pairs(frame, 31);
  io::Volume f_max;
  f_max.nx = nx;
  f_max.ny = ny;
  f_max.nz = nz;
  f_max.source = "max-mixture";
  // Softmax at β = 1e5: within (n − 1)/(e β) < 1e-4 of the max (gmf/core/aggregation.hpp).
  f_max.voxels = gmf::rasterize_mixture(
      mixture, frame, {.cutoff = 16.0, .tail = 0.0, .aggregation = gmf::Aggregation::kSoftmax, .beta = 1e5});
  io::Volume f_sum = f_max;
  f_sum.voxels = gmf::rasterize_mixture(mixture, frame, {.cutoff = 16.0});

  CameraOptions co;
  co.width = 96;
  co.height = 96;
  co.orbit_radius = 40.0;  // far and narrow: rays nearly parallel over the box
  co.fov_deg = 3.2;
  co.far = 80.0;
  const CameraSet cams = custom_orbit(co, {-35, 0, 50, 90}, {0, 70});
  RaymarchOptions ro;
  ro.step_voxels = 0.25;
  const RayMarcher march_max(f_max, frame, ro), march_sum(f_sum, frame, ro);
  const auto renderer = make_splat_renderer(Backend::kCpu);
  SplatSettings hard;
  hard.mode = MipMode::kMax;
  const std::span<const float> params = flat_params(mixture);
  std::vector<float> truth_max(96 * 96), truth_sum(96 * 96), splat(96 * 96);
  for (const CameraView& view : cams.views) {
    march_max.render(cams.intrinsics, view, truth_max);
    march_sum.render(cams.intrinsics, view, truth_sum);
    renderer->forward(params, cams.intrinsics, view, hard, splat);
    const double against_max = gmf::psnr(splat, truth_max), against_sum = gmf::psnr(splat, truth_sum);
    EXPECT_GE(against_max, 45.0) << view.name;
    // The overlaps matter: the sum's MIP is a different picture.
    EXPECT_LT(against_sum, against_max - 10.0) << view.name;
  }
}

}  // namespace
}  // namespace hisnegs::splat
