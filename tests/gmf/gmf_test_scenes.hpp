// SPDX-License-Identifier: Apache-2.0
// Shared fixtures of the gmf tests: a small volume rendered from 20 known
// Gaussians (make_scene) and its sparse grid (grid_of). No assertions here.
#pragma once

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <random>

#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/core/rasterize.hpp"
#include "io/sparse_grid.hpp"
#include "io/volume.hpp"

namespace hisnegs::gmf {

struct Scene {
  io::Volume volume;
  io::WorldFrame frame;
  GaussianMixture truth;
};

// 20 Gaussians with σ of 1.2-2 voxels, spread so that few overlap, rendered into a 48x48x24 volume.
inline Scene make_scene(std::uint64_t seed) {
  Scene s;
  s.volume.nx = 48;
  s.volume.ny = 48;
  s.volume.nz = 24;
  s.volume.source = "scene";
  s.frame = io::WorldFrame(48, 48, 24, Eigen::Vector3d(1.0, 1.0, 0.5));
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  const double voxel = s.frame.voxel_size().x();
  while (s.truth.size() < 20) {
    GaussianParams g;
    const Eigen::Vector3d ijk(6 + 36 * u(rng), 6 + 36 * u(rng), 5 + 14 * u(rng));
    const Eigen::Vector3d p = s.frame.world_from_index(ijk);
    bool close = false;
    for (const auto& t : s.truth) {
      close |= (Eigen::Vector3d(t.mean[0], t.mean[1], t.mean[2]) - p).norm() < 7 * voxel;
    }
    if (close) continue;
    for (int a = 0; a < 3; ++a) g.mean[a] = static_cast<float>(p[a]);
    for (int a = 0; a < 3; ++a) g.log_scale[a] = static_cast<float>(std::log((1.2 + 0.8 * u(rng)) * voxel));
    std::normal_distribution<double> gauss(0, 1);
    Eigen::Vector4d q(gauss(rng), gauss(rng), gauss(rng), gauss(rng));  // uniform random rotation
    q.normalize();
    g.rotation = {static_cast<float>(q[0]), static_cast<float>(q[1]), static_cast<float>(q[2]),
                  static_cast<float>(q[3])};
    const double a = 0.4 + 0.5 * u(rng);
    g.intensity_logit = static_cast<float>(std::log(a / (1 - a)));
    s.truth.push_back(g);
  }
  s.volume.voxels = rasterize_mixture(s.truth, s.frame, {.cutoff = 1e9});
  s.volume.normalization.method = io::NormalizationMethod::kMinMax;
  return s;
}

// The scene's sparse grid: threshold 0.02, band 2, optional background samples.
inline io::SparseGrid grid_of(const Scene& scene, double background_fraction) {
  io::SparseGridOptions so;
  so.threshold = 0.02;
  so.background_fraction = background_fraction;
  return io::build_sparse_grid(scene.volume, scene.frame.aspect(), so);
}

}  // namespace hisnegs::gmf
