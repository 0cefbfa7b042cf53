// SPDX-License-Identifier: Apache-2.0
// VolumeTerm: the stage-1 residual on a batch of sample blocks, its gradient
// through the core's VJPs, and the empty-space test of density control.
#include "splat/volume_term.hpp"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

#include "gmf/core/gaussian_math.hpp"
#include "gmf/core/param_layout.hpp"

namespace hisnegs::splat {
namespace {

constexpr std::size_t kP = gmf::kGaussianParamCount;

// What one block contributes: Σ r² and the gradient of (weight/n) Σ r² for the
// Gaussians that reach it.
struct BlockPart {
  double squares = 0;
  std::vector<std::uint32_t> ids;
  std::vector<double> grad;  // kP per id
};

// Squared distance from `p` to the box [lo, hi].
double box_distance2(const float* p, const std::array<float, 6>& box) {
  double d2 = 0;
  for (int a = 0; a < 3; ++a) {
    const double below = static_cast<double>(box[a]) - p[a], above = p[a] - static_cast<double>(box[3 + a]);
    const double d = std::max({below, above, 0.0});
    d2 += d * d;
  }
  return d2;
}

}  // namespace

void VolumeSamples::check() const {
  const std::size_t n = value.size();
  if (x.size() != n || y.size() != n || z.size() != n || weight.size() != n) {
    throw std::invalid_argument("VolumeSamples: arrays of different sizes");
  }
  if (block_begin.empty() || block_begin.front() != 0 || block_begin.back() != n) {
    throw std::invalid_argument("VolumeSamples: block_begin must run from 0 to the sample count");
  }
  for (std::size_t b = 0; b + 1 < block_begin.size(); ++b) {
    if (block_begin[b + 1] <= block_begin[b]) {
      throw std::invalid_argument("VolumeSamples: block " + std::to_string(b) + " is empty");
    }
  }
  for (std::size_t j = 0; j < n; ++j) {
    if (!std::isfinite(x[j]) || !std::isfinite(y[j]) || !std::isfinite(z[j]) || !std::isfinite(value[j]) ||
        !(weight[j] >= 0) || !std::isfinite(weight[j])) {
      throw std::invalid_argument("VolumeSamples: sample " + std::to_string(j) + " is not finite");
    }
  }
}

VolumeTerm::VolumeTerm(VolumeSamples samples, const gmf::MixtureModel& model, EmptySpaceTest empty)
    : samples_(std::move(samples)), model_(model), empty_(std::move(empty)) {
  samples_.check();
  if (samples_.blocks() == 0) throw std::invalid_argument("VolumeTerm: no samples");
  block_box_.resize(samples_.blocks());
  for (std::size_t b = 0; b < samples_.blocks(); ++b) {
    std::array<float, 6> box{INFINITY, INFINITY, INFINITY, -INFINITY, -INFINITY, -INFINITY};
    for (std::uint32_t j = samples_.block_begin[b]; j < samples_.block_begin[b + 1]; ++j) {
      const float p[3] = {samples_.x[j], samples_.y[j], samples_.z[j]};
      for (int a = 0; a < 3; ++a) {
        box[a] = std::min(box[a], p[a]);
        box[3 + a] = std::max(box[3 + a], p[a]);
      }
    }
    block_box_[b] = box;
  }
}

double VolumeTerm::add(std::span<const float> params, std::span<const std::uint32_t> blocks, double weight,
                       std::span<float> grad, bool max) const {
  gmf::MixtureModel model = model_;
  if (max) model.aggregation = gmf::Aggregation::kMax;
  if (params.size() % kP != 0 || grad.size() != params.size()) {
    throw std::invalid_argument("VolumeTerm::add: parameter and gradient sizes do not match");
  }
  const std::size_t K = params.size() / kP;
  std::size_t n = 0;
  for (std::uint32_t b : blocks) {
    if (b >= samples_.blocks()) throw std::out_of_range("VolumeTerm::add: block " + std::to_string(b));
    n += samples_.block_begin[b + 1] - samples_.block_begin[b];
  }
  if (n == 0) return 0.0;
  // A Gaussian reaches x only when m(x) <= δ, hence |x − μ| <= sqrt(δ) s_max.
  std::vector<double> reach2(K);
  tbb::parallel_for(std::size_t{0}, K, [&](std::size_t k) {
    const float* p = params.data() + kP * k;
    const double s = std::exp(static_cast<double>(
        std::max({p[gmf::kLogScale0], p[gmf::kLogScale0 + 1], p[gmf::kLogScale0 + 2]})));
    reach2[k] = model.cutoff * s * s;
  });
  const double scale = 2.0 * weight / static_cast<double>(n);  // ∂(weight Σ r² / n)/∂r = scale × r
  std::vector<BlockPart> parts(blocks.size());
  tbb::parallel_for(std::size_t{0}, blocks.size(), [&](std::size_t i) {
    const std::uint32_t b = blocks[i];
    BlockPart& part = parts[i];
    for (std::size_t k = 0; k < K; ++k) {
      if (box_distance2(params.data() + kP * k, block_box_[b]) <= reach2[k]) {
        part.ids.push_back(static_cast<std::uint32_t>(k));
      }
    }
    const std::size_t m = part.ids.size();
    std::vector<gmf::GaussianFrame<double>> frames(m);
    for (std::size_t g = 0; g < m; ++g) {
      double p[kP];
      std::copy_n(params.data() + kP * part.ids[g], kP, p);
      gmf::prepare_gaussian(p, frames[g]);
    }
    part.grad.assign(m * kP, 0.0);
    std::vector<double> term(m);
    std::vector<char> reaches(m);
    double dg[kP];
    for (std::uint32_t j = samples_.block_begin[b]; j < samples_.block_begin[b + 1]; ++j) {
      const double x[3] = {samples_.x[j], samples_.y[j], samples_.z[j]};
      gmf::PointTerms<double> t = gmf::no_terms<double>();
      for (std::size_t g = 0; g < m; ++g) {
        double z[3];
        reaches[g] = gmf::mahalanobis(frames[g], x, z) <= model.cutoff;
        if (!reaches[g]) continue;
        term[g] = gmf::evaluate_gaussian<double>(frames[g], x, nullptr);
        gmf::add_term(t, term[g], model);
      }
      const double f = gmf::terms_value(t, model);
      const double w = samples_.weight[j];
      const double r = w * (f - static_cast<double>(samples_.value[j]));
      part.squares += r * r;
      const double dL_df = scale * r * w;
      if (dL_df == 0.0) continue;
      for (std::size_t g = 0; g < m; ++g) {
        if (!reaches[g]) continue;
        const double df_dg = gmf::dvalue_dterm(term[g], t, model, f);
        const double c = dL_df * df_dg;
        if (c == 0.0) continue;
        gmf::evaluate_gaussian<double>(frames[g], x, dg);
        double* out = part.grad.data() + kP * g;
        for (std::size_t q = 0; q < kP; ++q) out[q] += c * dg[q];
      }
    }
  });
  double squares = 0;
  for (const BlockPart& part : parts) {
    squares += part.squares;
    for (std::size_t g = 0; g < part.ids.size(); ++g) {
      float* out = grad.data() + kP * part.ids[g];
      for (std::size_t q = 0; q < kP; ++q) out[q] += static_cast<float>(part.grad[kP * g + q]);
    }
  }
  return weight * squares / static_cast<double>(n);
}

bool VolumeTerm::centre_in_empty_space(const float* p) const {
  if (!empty_) return false;
  const double world[3] = {p[gmf::kMeanX], p[gmf::kMeanY], p[gmf::kMeanZ]};
  return empty_(world);
}

}  // namespace hisnegs::splat
