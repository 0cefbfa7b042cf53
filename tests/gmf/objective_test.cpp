// gmf/objective: the first-order loss ½ Σ w² (f_δ − V)² and its gradient on the
// small known scene: the gradient against Ridders differences of the value.
#include "gmf/objective.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "gmf/brick_index.hpp"
#include "gmf/samples.hpp"
#include "tests/gmf/gmf_test_scenes.hpp"
#include "tests/test_support.hpp"

namespace hisnegs::gmf {
namespace {

// The first-order objective's gradient is the derivative of its value.
TEST(GmfObjective, GradientMatchesItsValue) {
  const Scene scene = make_scene(13);
  const io::SparseGrid grid = grid_of(scene, 0.05);
  const SampleSet samples = extract_samples(grid, 1.0, 2);
  GaussianMixture m = scene.truth;
  for (auto& g : m) g.mean[0] += static_cast<float>(0.3 * scene.frame.voxel_size().x());
  const BrickIndex index = build_brick_index(m, samples, scene.frame, 1e9);
  const FitObjective objective(samples, index, m.size(), 1e9);
  std::vector<double> x(objective.parameters());
  for (std::size_t k = 0; k < m.size(); ++k) {
    const auto a = to_array(m[k]);
    for (int i = 0; i < kGaussianParamCount; ++i) x[11 * k + i] = a[i];
  }
  std::vector<double> grad(x.size());
  objective.evaluate(x.data(), grad.data());
  double largest = 0;
  for (double g : grad) largest = std::max(largest, std::abs(g));
  for (std::size_t i : {std::size_t{0}, std::size_t{4}, std::size_t{7}, std::size_t{10}, std::size_t{11 * 5 + 2},
                        std::size_t{11 * 9 + 8}, std::size_t{11 * 19 + 10}}) {
    auto f = [&](double v) {
      std::vector<double> y = x;
      y[i] = v;
      return objective.evaluate(y.data(), nullptr);
    };
    const double h0 = (i % 11) <= kMeanZ ? 0.1 * scene.frame.voxel_size().x() : 0.01;
    const double fd = testing::ridders_derivative(f, x[i], h0);
    EXPECT_NEAR(grad[i], fd, 1e-6 * std::max({std::abs(grad[i]), std::abs(fd), 1e-3 * largest})) << "parameter " << i;
  }
}

}  // namespace
}  // namespace hisnegs::gmf
