// SPDX-License-Identifier: Apache-2.0
// FitObjective: the loss ½ Σ r² and its gradient Jᵀr in one fused pass per sample
// block. The per-sample VJPs of gaussian_math.hpp are linear in dL/dm, so each
// Gaussian's x-dependent parts are accumulated (16 numbers) and chained through
// the rotation and sigmoid VJPs once per Gaussian at the end, instead of forming
// BlockCost's dense Jacobian sample by sample. Tested equal to BlockCost's Jᵀr.
#include "gmf/objective.hpp"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <span>
#include <stdexcept>
#include <string>
#include <vector>

#include "gmf/detail/candidates.hpp"
#include "gmf/core/gaussian_math.hpp"

namespace hisnegs::gmf {
namespace {

// What one Gaussian's gradient needs, summed over the samples it reaches:
// Σ dL/dm · z/s (the mean, rotated once at the end), Σ dL/dm · z_i² (log-scales),
// Σ 2 dL/dm · d (z/s)ᵀ (= dL/dR, row-major) and Σ dL/dg · e^{−m/2} (the intensity).
constexpr int kAccMean = 0, kAccScale = 3, kAccR = 6, kAccA = 15, kAccCount = 16;

// One term reaching the current sample.
struct Term {
  std::uint32_t k;
  double g, e, z[3];
  double w;  // softmax: e^{β (g − max g)}; max: 1 for the first largest term, else 0
};

}  // namespace

struct FitObjective::Blocks {
  const SampleSet* samples = nullptr;
  MixtureModel model;
  const BlockIndex* index = nullptr;  // not copied: on a large stack its lists are the fit's largest part
  std::vector<std::size_t> block;     // the sample blocks some Gaussian reaches
  // Per listed block, the ball holding its samples: centre (their mean) and
  // radius (their largest distance from it, with a relative margin of 1e-9).
  std::vector<std::array<double, 4>> ball;
  // After hold_fixed: Gaussians [0, frozen) are held; listed block c's free
  // candidates are free[free_begin[c] .. free_begin[c + 1]), and fixed[s] holds
  // the held terms at sample s.
  std::size_t frozen = 0;
  std::vector<std::size_t> free_begin;
  std::vector<std::uint32_t> free;
  std::vector<PointTerms<double>> fixed;

  [[nodiscard]] std::span<const std::uint32_t> candidates(std::size_t c) const {
    if (frozen == 0) return index->of(block[c]);
    return {free.data() + free_begin[c], free.data() + free_begin[c + 1]};
  }
  [[nodiscard]] const PointTerms<double>* held_terms(std::uint32_t s) const {
    return fixed.empty() ? nullptr : &fixed[s];
  }
};

FitObjective::FitObjective(const SampleSet& samples, const BlockIndex& index, std::size_t gaussians,
                           const MixtureModel& model)
    : blocks_(std::make_unique<Blocks>()), gaussians_(gaussians) {
  constant_ = unreached_loss(samples, index);
  blocks_->samples = &samples;
  blocks_->model = model;
  blocks_->index = &index;
  for (std::size_t b = 0; b < samples.blocks(); ++b) {
    const auto ids = index.of(b);
    const bool foreground = samples.block_begin[b] < samples.foreground;  // blocks hold one part only
    if (ids.empty()) {
      if (foreground) {
        for (std::uint32_t s = samples.block_begin[b]; s < samples.block_begin[b + 1]; ++s) {
          constant_foreground_se_ += samples.value[s] * samples.value[s];
        }
      }
      continue;
    }
    blocks_->block.push_back(b);
    const std::uint32_t s0 = samples.block_begin[b], s1 = samples.block_begin[b + 1];
    const std::array<double, 4> ball = detail::sample_ball(samples, s0, s1);
    blocks_->ball.push_back(ball);
  }
}

FitObjective::~FitObjective() = default;

namespace {

// Per chunk of blocks: the near candidates of the current block, their distances
// to the current sample and the terms that reach it.
struct ChunkScratch {
  std::vector<Term> terms;
  std::vector<std::uint32_t> near;  // the block's candidates that may reach one of its samples
  detail::CandidatePack pack;       // the near candidates
  std::vector<std::int64_t> offset;
  std::vector<double> slack, m, e, z, g, w;
};

// s.near and s.pack: the `candidates` of a block whose samples lie in `ball` that
// may reach one of them (√m at the centre within `reach` + the ball's radius).
void select_near(std::span<const std::uint32_t> candidates, const std::vector<double>& rows,
                 const std::array<double, 4>& ball, double reach, ChunkScratch& s) {
  const std::uint32_t* ids = candidates.data();
  const std::size_t n_ids = candidates.size();
  const std::size_t padded = (n_ids + detail::kCandidateAlign - 1) / detail::kCandidateAlign * detail::kCandidateAlign;
  s.offset.resize(padded);
  s.slack.resize(padded);
  for (std::size_t i = 0; i < n_ids; ++i) s.offset[i] = static_cast<std::int64_t>(ids[i] * detail::kGaussianRow);
  std::fill(s.offset.begin() + static_cast<std::ptrdiff_t>(n_ids), s.offset.end(), s.offset[0]);
  detail::candidate_slack(rows.data(), s.offset.data(), n_ids, ball.data(), ball[3], reach, s.slack.data());
  s.near.clear();
  for (std::size_t i = 0; i < n_ids; ++i) {
    if (s.slack[i] <= 0) s.near.push_back(ids[i]);
  }
  s.pack.assign(rows.data(), s.near.data(), s.near.size());
  if (s.m.size() < s.pack.stride) {
    s.m.resize(s.pack.stride);
    s.e.resize(s.pack.stride);
    s.z.resize(3 * s.pack.stride);
    s.g.resize(s.pack.stride);
    s.w.resize(s.pack.stride);
  }
}

// The model at sample x: s.terms (the near candidates within the support) and f,
// the sum, the softmax-weighted mean Σ w_k g_k, w = softmax(β g), with
// e^{β (g_k − max g)} computed once and kept for ∂f/∂g_k, `S` the softmax's Σ w,
// or the max (w = 1 for the first free term that is the max, unless a held term
// is larger; S = 1). `fixed` (or null): the held Gaussians' terms at x, which join
// the near ones.
double sample_value(const double x[3], const std::vector<GaussianFrame<double>>& frames, const MixtureModel& model,
                    const PointTerms<double>* fixed, ChunkScratch& s, double& S) {
  s.terms.clear();
  double sum = 0, top = -INFINITY;
  detail::candidate_distances(s.pack, x, s.m.data(), s.e.data(), s.z.data());
  for (std::size_t i = 0; i < s.pack.size; ++i) {
    if (s.m[i] > model.cutoff) continue;  // outside the support: contributes nothing
    Term t;
    t.k = s.near[i];
    t.e = s.e[i];
    t.g = frames[t.k].a * t.e;
    for (int j = 0; j < 3; ++j) t.z[j] = s.z[static_cast<std::size_t>(j) * s.pack.stride + i];
    s.g[s.terms.size()] = t.g;
    sum += t.g;
    top = std::max(top, t.g);
    s.terms.push_back(t);
  }
  S = 0;
  if (model.aggregation == Aggregation::kMax) {
    S = 1;
    const double held = fixed != nullptr ? fixed->max : 0.0;
    bool taken = !(top > held);  // a held term at least as large: no free term gets the gradient
    for (Term& t : s.terms) {
      t.w = !taken && t.g == top ? 1.0 : 0.0;
      taken = taken || t.w > 0;
    }
    return s.terms.empty() ? held : std::max(top, held);
  }
  if (model.aggregation != Aggregation::kSoftmax) return fixed ? fixed->sum + sum : sum;
  const bool held = fixed != nullptr && fixed->soft.S > 0;
  if (s.terms.empty()) return held ? softmax_value(fixed->soft) : 0.0;
  // e^{β g − shift β} for every term, shift the largest g of free and held alike
  const double shift = held ? std::max(top, fixed->soft.m / model.beta) : top;
  double W = 0;
  if (held) {
    const double r = std::exp(fixed->soft.m - model.beta * shift);
    S = fixed->soft.S * r;
    W = fixed->soft.W * r;
  }
  detail::shifted_exp(s.g.data(), s.terms.size(), model.beta, shift, s.w.data());
  for (std::size_t i = 0; i < s.terms.size(); ++i) {
    Term& t = s.terms[i];
    t.w = s.w[i];
    S += t.w;
    W += t.w * t.g;
  }
  return W / S;
}

// Adds one sample's dL/df to the accumulators (acc, kAccCount per Gaussian) of the
// Gaussians that reach it.
void accumulate_sample(const double x[3], double dL_df, double f, double S, const MixtureModel& model,
                       const std::vector<Term>& terms, const std::vector<GaussianFrame<double>>& frames, double* acc) {
  const bool soft = model.aggregation == Aggregation::kSoftmax;
  const bool max = model.aggregation == Aggregation::kMax;
  for (const Term& t : terms) {
    // w_k (1 + β (g_k − f)), the max's subgradient, or 1
    const double df_dg = soft ? t.w / S * (1.0 + model.beta * (t.g - f)) : max ? t.w : 1.0;
    if (df_dg == 0.0) continue;
    const double dL_dg = dL_df * df_dg;
    const double dL_dm = -0.5 * t.g * dL_dg;
    const GaussianFrame<double>& fr = frames[t.k];
    double* a = acc + kAccCount * static_cast<std::size_t>(t.k);
    const double zs[3] = {t.z[0] * fr.inv_scale[0], t.z[1] * fr.inv_scale[1], t.z[2] * fr.inv_scale[2]};
    const double d[3] = {x[0] - fr.mean[0], x[1] - fr.mean[1], x[2] - fr.mean[2]};
    for (int i = 0; i < 3; ++i) {
      a[kAccMean + i] += dL_dm * zs[i];
      a[kAccScale + i] += dL_dm * t.z[i] * t.z[i];
      const double dm2 = 2.0 * dL_dm * d[i];
      for (int j = 0; j < 3; ++j) a[kAccR + 3 * i + j] += dm2 * zs[j];
    }
    a[kAccA] += dL_dg * t.e;
  }
}

// One Gaussian's gradient from its summed accumulators: the once-per-Gaussian VJPs.
void finish_gradient(const GaussianFrame<double>& fr, const double (&a)[kAccCount], double* out) {
  for (int r = 0; r < 3; ++r) {
    out[kMeanX + r] =
        -2.0 * (fr.R[3 * r] * a[kAccMean] + fr.R[3 * r + 1] * a[kAccMean + 1] + fr.R[3 * r + 2] * a[kAccMean + 2]);
    out[kLogScale0 + r] = -2.0 * a[kAccScale + r];
  }
  rotation_vjp(fr, a + kAccR, out + kRotW);
  out[kLogit] = sigmoid_vjp(fr.a, a[kAccA]);
}

// The frames and candidate rows (detail::kGaussianRow each) of Gaussians [from, K)
// of `params`; those before `from` are left as they are.
void prepare_frames(const double* params, std::size_t from, std::size_t K, std::vector<GaussianFrame<double>>& frames,
                    std::vector<double>& rows) {
  frames.resize(K);
  rows.resize(K * detail::kGaussianRow);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(from, K, 256), [&](const tbb::blocked_range<std::size_t>& range) {
    for (std::size_t k = range.begin(); k != range.end(); ++k) {
      prepare_gaussian(params + kGaussianParamCount * k, frames[k]);
      detail::write_candidate_row(frames[k], rows.data() + k * detail::kGaussianRow);
    }
  });
}

// A candidate whose √m at the block's centre exceeds √cutoff by more than
// max_inv_scale × the block's radius reaches none of its samples (√m is a norm
// of x − μ). The margin keeps the test conservative under rounding, so the
// terms are exactly those of testing each sample.
double reach_of(const MixtureModel& model) { return std::sqrt(model.cutoff) * (1 + 1e-9) + 1e-12; }

// The terms of s.pack's candidates (s.near) at x, combined as `model` says.
PointTerms<double> terms_at(const double x[3], const std::vector<GaussianFrame<double>>& frames,
                            const MixtureModel& model, ChunkScratch& s) {
  PointTerms<double> t = no_terms<double>();
  detail::candidate_distances(s.pack, x, s.m.data(), s.e.data(), s.z.data());
  for (std::size_t i = 0; i < s.pack.size; ++i) {
    if (s.m[i] <= model.cutoff) add_term(t, frames[s.near[i]].a * s.e[i], model);
  }
  return t;
}

}  // namespace

void FitObjective::hold_fixed(const double* params, std::size_t frozen) {
  Blocks& bl = *blocks_;
  if (frozen == 0) return;
  if (bl.frozen > 0 || frozen > gaussians_) {
    throw std::invalid_argument("FitObjective::hold_fixed: " + std::to_string(frozen) + " of " +
                                std::to_string(gaussians_) + " Gaussians, " + std::to_string(bl.frozen) +
                                " held already");
  }
  const SampleSet& sm = *bl.samples;
  std::vector<GaussianFrame<double>> frames;
  std::vector<double> rows;
  prepare_frames(params, 0, frozen, frames, rows);
  const double reach = reach_of(bl.model);
  const std::size_t blocks = bl.block.size();
  bl.fixed.assign(sm.size(), no_terms<double>());
  std::vector<std::vector<std::uint32_t>> free_of(blocks);
  std::vector<double> block_loss(blocks, 0.0), block_fg(blocks, 0.0);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, blocks, 16), [&](const tbb::blocked_range<std::size_t>& range) {
    ChunkScratch scratch;
    std::vector<std::uint32_t> held;
    for (std::size_t c = range.begin(); c != range.end(); ++c) {
      const std::size_t b = bl.block[c];
      held.clear();
      for (std::uint32_t k : bl.index->of(b)) (k < frozen ? held : free_of[c]).push_back(k);
      if (held.empty()) continue;
      select_near(held, rows, bl.ball[c], reach, scratch);
      for (std::uint32_t s = sm.block_begin[b]; s < sm.block_begin[b + 1]; ++s) {
        const double x[3] = {sm.x[s], sm.y[s], sm.z[s]};
        bl.fixed[s] = terms_at(x, frames, bl.model, scratch);
        if (!free_of[c].empty()) continue;
        // reached by held Gaussians alone: a constant residual
        const double d = terms_value(bl.fixed[s], bl.model) - sm.value[s];
        block_loss[c] += 0.5 * sm.weight[s] * sm.weight[s] * d * d;
        if (sm.block_begin[b] < sm.foreground) block_fg[c] += d * d;
      }
    }
  });
  // The blocks with free candidates stay listed; the others join the constant (in block order).
  std::vector<std::size_t> kept;
  bl.free_begin.assign(1, 0);
  for (std::size_t c = 0; c < blocks; ++c) {
    if (free_of[c].empty()) {
      constant_ += block_loss[c];
      constant_foreground_se_ += block_fg[c];
      continue;
    }
    kept.push_back(c);
    bl.free.insert(bl.free.end(), free_of[c].begin(), free_of[c].end());
    bl.free_begin.push_back(bl.free.size());
  }
  for (std::size_t i = 0; i < kept.size(); ++i) {
    bl.block[i] = bl.block[kept[i]];
    bl.ball[i] = bl.ball[kept[i]];
  }
  bl.block.resize(kept.size());
  bl.ball.resize(kept.size());
  bl.frozen = frozen;
}

std::size_t FitObjective::held() const { return blocks_->frozen; }

double FitObjective::evaluate(const double* params, double* gradient, double* foreground_se) const {
  // Fixed chunks of residual blocks, each reduced sequentially into its own buffer
  // and combined in chunk order: the result does not depend on thread scheduling.
  constexpr std::size_t kChunks = 8;
  const Blocks& bl = *blocks_;
  const SampleSet& sm = *bl.samples;
  const MixtureModel& model = bl.model;
  const std::size_t K = gaussians_;
  std::vector<GaussianFrame<double>> frames;
  std::vector<double> rows;  // per Gaussian, one row of its candidate fields
  prepare_frames(params, bl.frozen, K, frames, rows);
  const double reach = reach_of(model);
  const std::size_t blocks = bl.block.size();
  std::vector<double> chunk_loss(kChunks, 0.0), chunk_fg(kChunks, 0.0);
  std::vector<std::vector<double>> chunk_acc(kChunks);
  tbb::parallel_for(std::size_t{0}, kChunks, [&](std::size_t chunk) {
    const std::size_t begin = blocks * chunk / kChunks, end = blocks * (chunk + 1) / kChunks;
    double loss = 0, fg = 0;
    std::vector<double>& acc = chunk_acc[chunk];
    if (gradient) acc.assign(K * kAccCount, 0.0);
    ChunkScratch scratch;
    for (std::size_t c = begin; c < end; ++c) {
      const std::size_t b = bl.block[c];
      const bool foreground = sm.block_begin[b] < sm.foreground;
      select_near(bl.candidates(c), rows, bl.ball[c], reach, scratch);
      for (std::uint32_t s = sm.block_begin[b]; s < sm.block_begin[b + 1]; ++s) {
        const double x[3] = {sm.x[s], sm.y[s], sm.z[s]};
        double S = 0;
        const double f = sample_value(x, frames, model, bl.held_terms(s), scratch, S);
        const double weight = sm.weight[s];
        const double r = weight * (f - sm.value[s]);
        loss += 0.5 * r * r;
        if (foreground_se && foreground) fg += (f - sm.value[s]) * (f - sm.value[s]);
        if (gradient) accumulate_sample(x, r * weight, f, S, model, scratch.terms, frames, acc.data());
      }
    }
    chunk_loss[chunk] = loss;
    chunk_fg[chunk] = fg;
  });
  double loss = constant_;
  if (foreground_se) *foreground_se = constant_foreground_se_;
  for (std::size_t chunk = 0; chunk < kChunks; ++chunk) {
    loss += chunk_loss[chunk];
    if (foreground_se) *foreground_se += chunk_fg[chunk];
  }
  if (!gradient) return loss;
  // Per Gaussian: the chunks' sums in chunk order, then the once-per-Gaussian VJPs.
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, K, 256), [&](const tbb::blocked_range<std::size_t>& range) {
    for (std::size_t k = range.begin(); k != range.end(); ++k) {
      if (k < bl.frozen) {  // held: no gradient
        std::fill_n(gradient + kGaussianParamCount * k, kGaussianParamCount, 0.0);
        continue;
      }
      double a[kAccCount] = {};
      for (std::size_t chunk = 0; chunk < kChunks; ++chunk) {
        const double* src = chunk_acc[chunk].data() + kAccCount * k;
        for (int i = 0; i < kAccCount; ++i) a[i] += src[i];
      }
      finish_gradient(frames[k], a, gradient + kGaussianParamCount * k);
    }
  });
  return loss;
}

}  // namespace hisnegs::gmf
