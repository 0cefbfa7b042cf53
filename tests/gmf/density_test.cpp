// SPDX-License-Identifier: Apache-2.0
// gmf/density: adaptive density control on the small known scene: a missing
// Gaussian is cloned back, an over-wide one split by Eq. 17, and the Gaussian
// budget gmf.gaussians is never exceeded.
#include "gmf/density.hpp"

#include <gtest/gtest.h>

#include <cmath>

#include "gmf/block_index.hpp"
#include "gmf/core/gaussian_mixture.hpp"
#include "gmf/samples.hpp"
#include "tests/gmf/gmf_test_scenes.hpp"

namespace hisnegs::gmf {
namespace {

TEST(GmfDensity, ClonesWhereAGaussianIsMissing) {
  const Scene scene = make_scene(17);
  const io::SparseGrid grid = grid_of(scene, 0.01);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture m;
  for (std::size_t k = 0; k < scene.truth.size(); ++k) {
    if (k != 3) m.push_back(scene.truth[k]);
  }
  GmfOptions o;
  o.aggregation = Aggregation::kSum;  // these tests fit the report's sum
  o.densify_fraction = 0.06;          // one clone and one split at most for K = 19
  const BlockIndex index = build_block_index(m, samples, scene.frame, o.mahalanobis_cutoff);
  const DensityChange change = adapt_density(m, samples, index, scene.frame, o, o.model(0));
  ASSERT_EQ(change.cloned, 1);
  const auto& clone = m[m.size() - 1];
  const auto& missing = scene.truth[3];
  const Eigen::Vector3d d(clone.mean[0] - missing.mean[0], clone.mean[1] - missing.mean[1],
                          clone.mean[2] - missing.mean[2]);
  EXPECT_LT(d.norm(), 1.5 * scene.frame.voxel_size().maxCoeff());  // at the strongest under-covered voxel
}

TEST(GmfDensity, SplitsAnOverwideGaussianByEq17) {
  const Scene scene = make_scene(19);
  const io::SparseGrid grid = grid_of(scene, 0.01);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture m = scene.truth;
  m[0].log_scale[1] += static_cast<float>(std::log(3.0));  // axis 1 three times too wide
  const GaussianParams before = m[0];
  GmfOptions o;
  o.aggregation = Aggregation::kSum;  // these tests fit the report's sum
  o.clone_residual = 0.99;            // splits only
  const BlockIndex index = build_block_index(m, samples, scene.frame, o.mahalanobis_cutoff);
  const DensityChange change = adapt_density(m, samples, index, scene.frame, o, o.model(0));
  ASSERT_EQ(change.split, 1);
  ASSERT_EQ(m.size(), scene.truth.size() + 1);
  // Eq. 17: scales × 0.8, means ± 0.5 s_max along the longest axis (column 1 of R).
  const Eigen::Matrix3d R = rotation_matrix(before);
  const double s_max = std::exp(static_cast<double>(before.log_scale[1]));
  const GaussianParams& a = m[0];
  const GaussianParams& b = m[m.size() - 1];
  for (int r = 0; r < 3; ++r) {
    EXPECT_NEAR(a.mean[r], before.mean[r] + 0.5 * s_max * R(r, 1), 1e-6);
    EXPECT_NEAR(b.mean[r], before.mean[r] - 0.5 * s_max * R(r, 1), 1e-6);
    EXPECT_NEAR(a.log_scale[r], before.log_scale[r] + std::log(0.8), 1e-6);
    EXPECT_EQ(b.log_scale[r], a.log_scale[r]);
  }
}

// With room for many splits and clones (densify_fraction 1, a low clone
// threshold, four Gaussians missing and one too wide) the mixture grows to
// exactly gmf.gaussians and no further; at or over the budget nothing is added.
TEST(GmfDensity, NeverExceedsTheGaussianBudget) {
  const Scene scene = make_scene(31);
  const io::SparseGrid grid = grid_of(scene, 0.01);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture start;
  for (std::size_t k = 0; k < scene.truth.size(); ++k) {
    if (k % 5 != 2) start.push_back(scene.truth[k]);
  }
  start[0].log_scale[1] += static_cast<float>(std::log(3.0));
  const int K = static_cast<int>(start.size());
  GmfOptions o;
  o.aggregation = Aggregation::kSum;  // these tests fit the report's sum
  o.densify_fraction = 1.0;
  o.clone_residual = 0.05;
  const BlockIndex index = build_block_index(start, samples, scene.frame, o.mahalanobis_cutoff);

  // Unlimited (the default budget): several Gaussians would be added.
  GaussianMixture m = start;
  const DensityChange free = adapt_density(m, samples, index, scene.frame, o, o.model(0));
  ASSERT_GE(free.split + free.cloned, 3);

  for (const int budget : {K + 2, K + 1, K, K - 3}) {
    o.gaussians = budget;
    m = start;
    const DensityChange change = adapt_density(m, samples, index, scene.frame, o, o.model(0));
    const int added = std::max(0, budget - K);
    EXPECT_EQ(change.split + change.cloned, added) << "budget " << budget;
    EXPECT_EQ(m.size(), static_cast<std::size_t>(K + added)) << "budget " << budget;
  }
}

// A raw stack's noise peak (a dim voxel at 0.25 where the model is near 0) draws a
// clone while gmf.clone_floor is 0, and none once the floor (the background's 99.9th
// percentile, as the fit stage sets it) is at or above it; a missing Gaussian above
// the floor is still cloned back.
TEST(GmfDensity, ClonesNoNoisePeakBelowTheCloneFloor) {
  const Scene scene = make_scene(17);
  const io::SparseGrid grid = grid_of(scene, 0.01);
  SampleSet samples = extract_samples(grid, 1.0, 2);
  GmfOptions o;
  o.aggregation = Aggregation::kSum;
  o.densify_fraction = 0.5;
  const GaussianMixture full = scene.truth;
  const SampleSet clean = samples;
  // Noise peaks: the dimmest foreground samples lifted to 0.25.
  int peaks = 0;
  for (std::uint32_t s = 0; s < samples.foreground && peaks < 5; ++s) {
    if (samples.value[s] < 0.03f) {
      samples.value[s] = 0.25f;
      ++peaks;
    }
  }
  ASSERT_EQ(peaks, 5);
  const BlockIndex index = build_block_index(full, samples, scene.frame, o.mahalanobis_cutoff);
  const auto clones = [&](const SampleSet& set, double floor) {
    GaussianMixture m = full;
    o.clone_floor = floor;
    return adapt_density(m, set, index, scene.frame, o, o.model(0)).cloned;
  };
  // Without a floor the peaks draw clones; with the floor at their level they draw
  // none: exactly the clones of the stack without them.
  EXPECT_GT(clones(samples, 0.0), clones(clean, 0.0));
  EXPECT_EQ(clones(samples, 0.3), clones(clean, 0.3));
  // The missing Gaussian (its voxels well above the floor) is still cloned back.
  GaussianMixture missing;
  for (std::size_t k = 0; k < scene.truth.size(); ++k) {
    if (k != 3) missing.push_back(scene.truth[k]);
  }
  o.clone_floor = 0.05;
  const BlockIndex index2 = build_block_index(missing, samples, scene.frame, o.mahalanobis_cutoff);
  EXPECT_GE(adapt_density(missing, samples, index2, scene.frame, o, o.model(0)).cloned, 1);
}

}  // namespace
}  // namespace hisnegs::gmf
