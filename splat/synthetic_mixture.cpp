// SPDX-License-Identifier: Apache-2.0
// make_synthetic_mixture: random walks with momentum, Gaussians spread evenly over
// them; log-normal scales whose means are the Table 3 values.
#include "splat/synthetic_mixture.hpp"

#include <algorithm>
#include <cmath>
#include <random>

#include "gmf/core/gaussian_math.hpp"

namespace hisnegs::splat {

gmf::GaussianMixture make_synthetic_mixture(const SyntheticMixtureOptions& o) {
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<double> u(-1, 1);
  std::normal_distribution<double> n(0, 1);
  gmf::GaussianMixture mixture;
  mixture.reserve(static_cast<std::size_t>(o.gaussians));
  const int per_path = std::max(1, (o.gaussians + o.paths - 1) / o.paths);
  while (static_cast<int>(mixture.size()) < o.gaussians) {
    double p[3] = {u(rng) * o.box[0], u(rng) * o.box[1], u(rng) * o.box[2]};
    double d[3] = {n(rng), n(rng), n(rng)};
    for (int i = 0; i < per_path && static_cast<int>(mixture.size()) < o.gaussians; ++i) {
      // Turn a little, step 0.01, reflect at the box.
      double norm = 0;
      for (int a = 0; a < 3; ++a) {
        d[a] += 0.3 * n(rng);
        norm += d[a] * d[a];
      }
      norm = std::sqrt(norm);
      for (int a = 0; a < 3; ++a) {
        p[a] += 0.01 * d[a] / norm;
        if (std::abs(p[a]) > o.box[a]) {
          p[a] = std::clamp(p[a], -o.box[a], o.box[a]);
          d[a] = -d[a];
        }
      }
      gmf::GaussianParams g;
      for (int a = 0; a < 3; ++a) {
        g.mean[a] = static_cast<float>(p[a]);
        // E[exp(N(μ, σ²))] = exp(μ + σ²/2) = mean_scale
        const double mu = std::log(o.mean_scale[a]) - 0.5 * o.log_scale_sigma * o.log_scale_sigma;
        g.log_scale[a] = static_cast<float>(mu + o.log_scale_sigma * n(rng));
      }
      double q[4] = {n(rng), n(rng), n(rng), n(rng)};
      const double qn = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
      for (int a = 0; a < 4; ++a) g.rotation[a] = static_cast<float>(q[a] / qn);
      const double a = 0.15 + 0.8 * (0.5 + 0.5 * u(rng));
      g.intensity_logit = static_cast<float>(gmf::logit(a));
      mixture.push_back(g);
    }
  }
  return mixture;
}

}  // namespace hisnegs::splat
