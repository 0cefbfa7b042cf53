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

namespace {

// A foreground sample the model covers too little.
struct Candidate {
  double residual;
  std::size_t sample;
};

// Each Gaussian's share of the squared residuals (g_k / f for a sum, its softmax
// weight for a softmax mixture, 1 for the largest term of a max: the dominant
// Gaussian owns the error), and the
// foreground samples whose model falls short by more than clone_residual.
std::vector<double> error_shares(const GaussianMixture& mixture, const SampleSet& samples, const BlockIndex& index,
                                 const GmfOptions& options, const MixtureModel& model, std::vector<Candidate>& under) {
  const bool soft = model.aggregation == Aggregation::kSoftmax;
  const std::size_t K = mixture.size();
  std::vector<GaussianFrame<double>> frames(K);
  for (std::size_t k = 0; k < K; ++k) frames[k] = frame_of(mixture[k]);
  std::vector<double> error(K, 0.0);
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
      const double r = terms_value(all, model) - samples.value[s];
      for (std::size_t i : reach) {
        const double share = soft                                     ? std::exp(model.beta * g[i] - all.soft.m) / all.soft.S
                             : model.aggregation == Aggregation::kMax ? dvalue_dterm(g[i], all, model, all.max)
                                                                      : g[i] / all.sum;
        error[ids[i]] += share * r * r;
      }
      if (s < samples.foreground && -r > options.clone_residual && samples.value[s] > options.clone_floor) {
        under.push_back({-r, s});
      }
    }
  }
  return error;
}

// Split: error above mean + 2 sd, largest first, at most `per_call` and `room`;
// the twins are appended to `added`. Returns how many.
int split_worst(GaussianMixture& mixture, const std::vector<double>& error, const GmfOptions& options, double voxel,
                int per_call, int& room, std::vector<GaussianParams>& added) {
  const std::size_t K = error.size();
  const double mean = K ? std::accumulate(error.begin(), error.end(), 0.0) / K : 0.0;
  double var = 0;
  for (double e : error) var += (e - mean) * (e - mean);
  const double sd = K ? std::sqrt(var / K) : 0.0;
  std::vector<std::size_t> order(K);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(),
            [&](std::size_t a, std::size_t b) { return error[a] > error[b] || (error[a] == error[b] && a < b); });
  int split = 0;
  for (std::size_t k : order) {
    if (split >= per_call || room <= 0 || error[k] <= mean + 2 * sd) break;
    GaussianParams& p = mixture[k];
    if (std::exp(p.log_scale[longest_axis(p)]) <= voxel) continue;  // already at the voxel scale: splitting cannot help
    added.push_back(split_gaussian(p, options.split_offset, options.split_scale));
    ++split;
    --room;
  }
  return split;
}

// Clone: the strongest under-covered samples, at least two voxels apart, at most
// `per_call` and `room`; appended to `added`. Returns how many.
int clone_under(std::vector<Candidate> under, const SampleSet& samples, const io::WorldFrame& frame, bool soft,
                int per_call, int& room, std::vector<GaussianParams>& added) {
  std::sort(under.begin(), under.end(), [](const Candidate& a, const Candidate& b) {
    return a.residual > b.residual || (a.residual == b.residual && a.sample < b.sample);
  });
  std::vector<Eigen::Vector3d> placed;
  const double min_dist = 2.0 * frame.voxel_size().maxCoeff();
  int cloned = 0;
  for (const Candidate& c : under) {
    if (cloned >= per_call || room <= 0) break;
    const Eigen::Vector3d p(samples.x[c.sample], samples.y[c.sample], samples.z[c.sample]);
    bool near = false;
    for (const auto& q : placed) near = near || (q - p).norm() < min_dist;
    if (near) continue;
    placed.push_back(p);
    // A max-mixture shows the brightest term alone: the new Gaussian must reach V by
    // itself. A sum adds it to what is there: it fills the gap V − f.
    const double a = soft ? samples.value[c.sample] : c.residual;
    added.push_back(isotropic_gaussian(p, frame.voxel_size(), a));
    ++cloned;
    --room;
  }
  return cloned;
}

}  // namespace

DensityChange adapt_density(GaussianMixture& mixture, const SampleSet& samples, const BlockIndex& index,
                            const io::WorldFrame& frame, const GmfOptions& options, const MixtureModel& model) {
  const std::size_t K = mixture.size();
  std::vector<Candidate> under;
  const std::vector<double> error = error_shares(mixture, samples, index, options, model, under);
  const int per_call = std::max(1, static_cast<int>(options.densify_fraction * static_cast<double>(K)));
  int room = options.gaussians - static_cast<int>(K);
  std::vector<GaussianParams> added;
  DensityChange change;
  change.split = split_worst(mixture, error, options, frame.voxel_size().maxCoeff(), per_call, room, added);
  change.cloned = clone_under(std::move(under), samples, frame, model.aggregation != Aggregation::kSum, per_call,
                              room, added);
  for (const auto& p : added) mixture.push_back(p);
  return change;
}

}  // namespace hisnegs::gmf
