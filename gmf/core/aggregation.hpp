// SPDX-License-Identifier: Apache-2.0
// How the terms g_k of the Gaussians reaching a point combine into one value,
// with its derivative: the one policy of the 3D mixture (stage 1 fits it) and
// the 2D splat (stage 2 renders and trains it; splat::MipMode is this enum, soft
// = kSoftmax, hard = kMax). Three ways: the sum (report Eq. 1), the
// softmax-weighted mean of report Eq. 8, f_β = Σ_k w_k g_k with w = softmax(β g),
// which tends to max_k g_k as β grows, and the max itself, what a MIP viewer and
// the ground truth compute (its derivative is the subgradient: 1 for the largest
// term, 0 for the others, as max-pooling's). The softmax is kept online in
// log-sum-exp form so any number of terms, in any order and in groups, combine
// without overflow. __host__ __device__, no allocation.
//
// Why the max matters (docs/benchmarks.md "Hard MIP"): at β = 50 a softmax over
// dim terms (g ≈ 0.01–0.05, e^{βg} ≈ 1.6–12) is close to their mean, so a fit
// or training at β alone never sees dim halos that the max shows.
#pragma once

#include <cmath>

#include "gmf/core/hd.hpp"

namespace hisnegs::gmf {

enum class Aggregation { kSum, kSoftmax, kMax };

// How a mixture's value at a point is formed: which terms count (m <= cutoff, the
// Mahalanobis support δ) and how they combine (sum, softmax at beta, or max).
struct MixtureModel {
  Aggregation aggregation = Aggregation::kSum;
  double beta = 1.0;     // softmax only, > 0
  double cutoff = 16.0;  // δ
};

// The config and file name of an aggregation: sum, softmax or max.
inline const char* describe_aggregation(Aggregation a) {
  return a == Aggregation::kSum ? "sum" : a == Aggregation::kSoftmax ? "softmax" : "max";
}

// The online softmax of some terms: m = max β g so far, S = Σ e^{β g − m},
// W = Σ e^{β g − m} g; the value is W / S (0 when there is no term, S = 0).
template <class T>
struct SoftMaxState {
  T m, S, W;
};

template <class T>
HISNEGS_HD void softmax_init(SoftMaxState<T>& st) {
  st.m = -INFINITY;
  st.S = T(0);
  st.W = T(0);
}

template <class T>
HISNEGS_HD void softmax_add(SoftMaxState<T>& st, T g, T beta) {
  using std::exp;
  const T bg = beta * g;
  if (bg > st.m) {
    const T r = exp(st.m - bg);  // 0 for the first term (m = −∞)
    st.S = st.S * r + T(1);
    st.W = st.W * r + g;
    st.m = bg;
  } else {
    const T e = exp(bg - st.m);
    st.S += e;
    st.W += e * g;
  }
}

// The state of the union of two sets of terms (b merged into a).
template <class T>
HISNEGS_HD void softmax_merge(SoftMaxState<T>& a, const SoftMaxState<T>& b) {
  using std::exp;
  if (!(b.S > T(0))) return;
  if (!(a.S > T(0))) {
    a = b;
    return;
  }
  if (b.m > a.m) {
    const T r = exp(a.m - b.m);
    a.S = a.S * r + b.S;
    a.W = a.W * r + b.W;
    a.m = b.m;
  } else {
    const T r = exp(b.m - a.m);
    a.S += b.S * r;
    a.W += b.W * r;
  }
}

template <class T>
HISNEGS_HD T softmax_value(const SoftMaxState<T>& st) {
  return st.S > T(0) ? st.W / st.S : T(0);
}

// The terms reaching one point, combined as a MixtureModel says: their sum, their
// online softmax or their max (only the one the model uses is kept up to date, the
// others stay at their empty value; terms are positive, so an empty max is 0). Also what a computation holds fixed: the brick
// solver's neighbours, as one PointTerms per sample that the free terms add to.
template <class T>
struct PointTerms {
  T sum;
  SoftMaxState<T> soft;
  T max;
};
template <class T>
HISNEGS_HD PointTerms<T> no_terms() {
  PointTerms<T> t;
  t.sum = T(0);
  softmax_init(t.soft);
  t.max = T(0);
  return t;
}
template <class T>
HISNEGS_HD void add_term(PointTerms<T>& t, T g, const MixtureModel& model) {
  if (model.aggregation == Aggregation::kSum) {
    t.sum += g;
  } else if (model.aggregation == Aggregation::kSoftmax) {
    softmax_add(t.soft, g, T(model.beta));
  } else if (g > t.max) {
    t.max = g;
  }
}
// f at the point: the sum, the softmax-weighted mean W / S, or the max (0 with no term).
template <class T>
HISNEGS_HD T terms_value(const PointTerms<T>& t, const MixtureModel& model) {
  if (model.aggregation == Aggregation::kSum) return t.sum;
  return model.aggregation == Aggregation::kSoftmax ? softmax_value(t.soft) : t.max;
}

// ∂f_β/∂g_k = w_k (1 + β (g_k − f)), w_k = e^{β g_k − m} / S: the derivative with
// respect to one term, from the final m, S and value f of all the terms.
template <class T>
HISNEGS_HD T softmax_dvalue_dterm(T g, T beta, T m, T S, T f) {
  using std::exp;
  const T w = exp(beta * g - m) / S;
  return w * (T(1) + beta * (g - f));
}

// ∂f/∂g_k of one term g_k of a point whose terms are `t` and value f =
// terms_value(t, model): 1 (sum), w_k (1 + β (g_k − f)) (softmax), and for the
// max its subgradient, 1 for the largest term and 0 for the others (a term equal
// to the max is the largest; exact ties, of measure zero, each get 1).
template <class T>
HISNEGS_HD T dvalue_dterm(T g, const PointTerms<T>& t, const MixtureModel& model, T f) {
  if (model.aggregation == Aggregation::kSum) return T(1);
  if (model.aggregation == Aggregation::kSoftmax) return softmax_dvalue_dterm(g, T(model.beta), t.soft.m, t.soft.S, f);
  return g >= t.max ? T(1) : T(0);
}

}  // namespace hisnegs::gmf
