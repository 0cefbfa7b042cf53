// SPDX-License-Identifier: Apache-2.0
// adapt_density: per-sample residuals through the block index, error shares, and
// which Gaussians to split (Eq. 17) and where to add new ones (density_ops.hpp).
#include "gmf/density.hpp"

#include <algorithm>
#include <cmath>
#include <numeric>

#include "gmf/core/aggregation.hpp"
#include "gmf/core/density_ops.hpp"
#include "gmf/core/gaussian_math.hpp"

namespace hisnegs::gmf {

DensityChange adapt_density(GaussianMixture& mixture, const SampleSet& samples, const BlockIndex& index,
                            const io::WorldFrame& frame, const GmfOptions& options, const MixtureModel& model) {
  const bool soft = model.aggregation == Aggregation::kSoftmax;
  DensityChange change;
  const std::size_t K = mixture.size();
  std::vector<GaussianFrame<double>> frames(K);
  for (std::size_t k = 0; k < K; ++k) frames[k] = frame_of(mixture[k]);
  std::vector<double> error(K, 0.0);
  struct Candidate {
    double residual;
    std::size_t sample;
  };
  std::vector<Candidate> under;
  std::vector<double> g;
  std::vector<std::size_t> reach;
  for (std::size_t b = 0; b < samples.blocks(); ++b) {
    const auto ids = index.of(b);
    g.resize(ids.size());
    for (std::uint32_t s = samples.block_begin[b]; s < samples.block_begin[b + 1]; ++s) {
      const double x[3] = {samples.x[s], samples.y[s], samples.z[s]};
      PointTerms<double> all = no_terms<double>();
      reach.clear();
      for (std::size_t i = 0; i < ids.size(); ++i) {
        double z[3];
        if (mahalanobis(frames[ids[i]], x, z) > model.cutoff) continue;
        g[i] = evaluate_gaussian<double>(frames[ids[i]], x, nullptr);
        add_term(all, g[i], model);
        reach.push_back(i);
      }
      const double f = terms_value(all, model);
      const double r = f - samples.value[s];
      // Each Gaussian's share of the sample's squared residual: g_k / f for a sum,
      // its softmax weight for a max-mixture (the dominant Gaussian owns the error).
      for (std::size_t i : reach) {
        const double share = soft ? std::exp(model.beta * g[i] - all.soft.m) / all.soft.S : g[i] / all.sum;
        error[ids[i]] += share * r * r;
      }
      if (s < samples.foreground && -r > options.clone_residual && samples.value[s] > options.clone_floor) {
        under.push_back({-r, s});
      }
    }
  }
  const int per_call = std::max(1, static_cast<int>(options.densify_fraction * static_cast<double>(K)));
  int room = options.gaussians - static_cast<int>(K);
  const double voxel = frame.voxel_size().maxCoeff();

  // Split: error above mean + 2 sd, largest first.
  const double mean = K ? std::accumulate(error.begin(), error.end(), 0.0) / K : 0.0;
  double var = 0;
  for (double e : error) var += (e - mean) * (e - mean);
  const double sd = K ? std::sqrt(var / K) : 0.0;
  std::vector<std::size_t> order(K);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(),
            [&](std::size_t a, std::size_t b) { return error[a] > error[b] || (error[a] == error[b] && a < b); });
  std::vector<GaussianParams> added;
  for (std::size_t k : order) {
    if (change.split >= per_call || room <= 0 || error[k] <= mean + 2 * sd) break;
    GaussianParams& p = mixture[k];
    if (std::exp(p.log_scale[longest_axis(p)]) <= voxel) continue;  // already at the voxel scale: splitting cannot help
    const GaussianParams twin = split_gaussian(p, options.split_offset, options.split_scale);
    added.push_back(twin);
    ++change.split;
    --room;
  }
  // Clone: strongest under-covered samples, at least two voxels apart.
  std::sort(under.begin(), under.end(), [](const Candidate& a, const Candidate& b) {
    return a.residual > b.residual || (a.residual == b.residual && a.sample < b.sample);
  });
  std::vector<Eigen::Vector3d> placed;
  const double min_dist = 2.0 * voxel;
  for (const Candidate& c : under) {
    if (change.cloned >= per_call || room <= 0) break;
    const Eigen::Vector3d p(samples.x[c.sample], samples.y[c.sample], samples.z[c.sample]);
    bool near = false;
    for (const auto& q : placed) near = near || (q - p).norm() < min_dist;
    if (near) continue;
    placed.push_back(p);
    // A max-mixture shows the brightest term alone: the new Gaussian must reach V by
    // itself. A sum adds it to what is there: it fills the gap V − f.
    const double a = soft ? samples.value[c.sample] : c.residual;
    const GaussianParams g2 = isotropic_gaussian(p, frame.voxel_size(), a);
    added.push_back(g2);
    ++change.cloned;
    --room;
  }
  for (const auto& p : added) mixture.push_back(p);
  return change;
}

}  // namespace hisnegs::gmf
