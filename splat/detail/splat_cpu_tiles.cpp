// SPDX-License-Identifier: Apache-2.0
// Tile kernels of the CPU splatting back end (see splat_cpu_tiles.hpp): for each
// Gaussian of a tile, only the rows its δ ellipse crosses and, in each row, only
// the SIMD chunks of its column span are evaluated; lanes are masked by q <= δ.
// Compiled once per instruction set by Highway (foreach_target) and dispatched.
// Highway's foreach_target.h must come before its per-target headers.
// clang-format off
#undef HWY_TARGET_INCLUDE
#define HWY_TARGET_INCLUDE "splat/detail/splat_cpu_tiles.cpp"
#include <hwy/foreach_target.h>  // IWYU pragma: keep
#include <hwy/highway.h>
#include <hwy/contrib/math/math-inl.h>
// clang-format on

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "splat/detail/splat_cpu_tiles.hpp"

HWY_BEFORE_NAMESPACE();
namespace hisnegs::splat::detail {
namespace HWY_NAMESPACE {
namespace hn = hwy::HWY_NAMESPACE;

// ln x for x > 0 to ~1e-6 absolute, without libm (it dominated the culling's cost):
// x = 2^e · r with r in [√½, √2), ln r = 2 atanh(z), z = (r − 1)/(r + 1), |z| < 0.172.
inline float fast_log(float x) {
  std::uint32_t bits;
  std::memcpy(&bits, &x, sizeof bits);
  int e = static_cast<int>((bits >> 23) & 0xff) - 127;
  bits = (bits & 0x007fffffu) | 0x3f800000u;  // mantissa in [1, 2)
  float r;
  std::memcpy(&r, &bits, sizeof r);
  if (r > 1.41421356f) {
    r *= 0.5f;
    ++e;
  }
  const float z = (r - 1.0f) / (r + 1.0f), z2 = z * z;
  const float series = z * (2.0f + z2 * (2.0f / 3.0f + z2 * (2.0f / 5.0f + z2 * (2.0f / 7.0f))));
  return static_cast<float>(e) * 0.69314718f + series;
}
// fast_log's error, and float rounding of the bound, never make a cutoff too small:
// cutoffs are raised by this margin (in q units) before use.
constexpr float kCutoffMargin = 1e-3f;

// 2^y for y <= 0 (correct up to y = 127) in SIMD: y = k + r with k = round(y) and
// |r| <= ½ exact, 2^r by its degree-6 Taylor polynomial (relative error 1.2e-7),
// 2^k added to the exponent bits. k comes from the float's own rounding: adding
// 1.5·2^23 leaves round(y) in the low mantissa bits, so (bits << 23) is k << 23
// and no float-to-int conversion (with its overflow fix-ups) is needed. Below
// y = −126 the result is a value under 2e-38 instead of 0, harmless in sums and
// products with the softmax terms. Fewer than half the instructions of hn::Exp,
// which handles every x; the tile kernels spend most of their time here.
constexpr float kLog2e = 1.44269504f;
template <class D, class V>
HWY_INLINE V Exp2NonPositive(D d, V y) {
  const hn::RebindToSigned<D> di;
  const auto magic = hn::Set(d, 12582912.0f);  // 1.5 · 2^23
  y = hn::Max(y, hn::Set(d, -126.0f));
  const auto shifted = hn::Add(y, magic);
  const auto r = hn::Sub(y, hn::Sub(shifted, magic));
  // Estrin's scheme: three multiply-adds deep instead of Horner's six (the kernels
  // are bound by this latency more than by instruction count).
  const auto r2 = hn::Mul(r, r), r4 = hn::Mul(r2, r2);
  const auto p01 = hn::MulAdd(hn::Set(d, 6.9314718e-1f), r, hn::Set(d, 1.0f));
  const auto p23 = hn::MulAdd(hn::Set(d, 5.5504109e-2f), r, hn::Set(d, 2.4022651e-1f));
  const auto p45 = hn::MulAdd(hn::Set(d, 1.3333558e-3f), r, hn::Set(d, 9.6181291e-3f));
  const auto p456 = hn::MulAdd(hn::Set(d, 1.5403530e-4f), r2, p45);
  const auto p = hn::MulAdd(p456, r4, hn::MulAdd(p23, r2, p01));
  return hn::BitCast(d, hn::Add(hn::BitCast(di, p), hn::ShiftLeft<23>(hn::BitCast(di, shifted))));
}
// e^x = 2^{x log2 e}; the product adds a relative error of 6e-8·|x| (5e-7 at the
// δ = 16 edge of a Gaussian, where e^x is 3e-4). Hot loops fold log2 e into their
// constants and call Exp2NonPositive directly.
template <class D, class V>
HWY_INLINE V ExpNonPositive(D d, V x) {
  return Exp2NonPositive(d, hn::Mul(x, hn::Set(d, kLog2e)));
}

// out = in · log2 e for a tile's pixels (per-pixel maxima into base 2).
inline void times_log2e(const float* in, float* out) {
  const hn::ScalableTag<float> d;
  for (int at = 0; at < kTileSize * kTileSize; at += static_cast<int>(hn::Lanes(d))) {
    hn::Store(hn::Mul(hn::Load(d, in + at), hn::Set(d, kLog2e)), d, out + at);
  }
}

// Culling by per-row floors. A term is skipped when it cannot matter:
// hard MIP, g <= m (exact); soft-MIP, β g < M − skip_log_weight (weight below
// e^-skip, M the pixel's largest β g). With the row's smallest bound, g = a e^{-q/2}
// is below it wherever q > 2 (ln_peak − ln_floor[r]) with ln_peak = ln a (hard) or
// ln(β a) (soft): that q is the row's effective cutoff. ln_floor[r] is the row's
// smallest ln m (hard, running) or ln(M_row − skip) (soft, final), −∞ when nothing
// can be skipped yet; +∞ for rows off the image.
struct RowFloors {
  HWY_ALIGN float ln_floor[kTileSize];
  float tile_floor = 0.0f;  // the smallest ln_floor of the tile's rows

  // Hard: from the running ln max of every pixel (padding columns hold +∞).
  void from_log_max(const TileFrame& f, const float* lm) {
    const hn::ScalableTag<float> d;
    const int N = static_cast<int>(hn::Lanes(d));
    for (int r = 0; r < kTileSize; ++r) {
      auto lowest = hn::Load(d, lm + r * kTileSize);
      for (int c = N; c < kTileSize; c += N) lowest = hn::Min(lowest, hn::Load(d, lm + r * kTileSize + c));
      ln_floor[r] = r < f.height ? hn::GetLane(hn::MinOfLanes(d, lowest)) : std::numeric_limits<float>::infinity();
    }
    tile_floor = min_of_rows(f);
  }
  // Soft: from the final β-scaled maxima M (+∞ where no Gaussian reaches the pixel:
  // no term is evaluated there). `exact` (skip 0): nothing is skipped.
  void from_soft_max(const TileFrame& f, const float* M, bool exact) {
    std::fill(ln_floor + f.height, ln_floor + kTileSize, std::numeric_limits<float>::infinity());
    for (int r = 0; r < f.height; ++r) {
      float lowest = std::numeric_limits<float>::infinity();
      for (int c = 0; c < f.width; ++c) lowest = std::min(lowest, M[r * kTileSize + c]);
      const float floor = lowest - f.k.skip_log_weight;
      ln_floor[r] = (exact || !(floor > 0.0f))                        ? -std::numeric_limits<float>::infinity()
                    : floor == std::numeric_limits<float>::infinity() ? floor
                                                                      : fast_log(floor);
    }
    tile_floor = min_of_rows(f);
  }
  [[nodiscard]] float min_of_rows(const TileFrame& f) const {
    float lowest = ln_floor[0];
    for (int r = 1; r < f.height; ++r) lowest = std::min(lowest, ln_floor[r]);
    return lowest;
  }
  // The largest row cutoff of the tile for a Gaussian with peak ln_peak; row r's
  // own is min(δ, 2 (ln_peak − ln_floor[r]) + margin).
  [[nodiscard]] float cutoff_of_tile(float ln_peak, float delta) const {
    return std::min(delta, 2.0f * (ln_peak - tile_floor) + kCutoffMargin);
  }
  // True once no Gaussian of amplitude below a_bound (the list is amplitude
  // descending in kAmplitudeBuckets buckets, so every later one is below this one's + 1/1024)
  // reaches any pixel within its cutoff.
  [[nodiscard]] bool none_after(const TileFrame& f, float amp, float ln_beta) const {
    const float ln_bound = fast_log(amp + 1.0f / kAmplitudeBuckets) + (f.k.soft() ? ln_beta : 0.0f);
    return !(cutoff_of_tile(ln_bound, f.k.cutoff) > 0.0f);
  }
};
constexpr int kRefreshEvery = 8;  // entries per batch: the running row floors are refreshed and the
                                  // whole-tile test run (batch_hits) once per batch

// One Gaussian's columns in every row of a tile, computed for all rows at once in
// SIMD (rows across lanes): row r evaluates columns [lo[r], hi[r]] (empty when
// hi < lo) with the q cutoff cut[r]; dy[r] = py − v. The columns are those whose
// centres can lie inside q <= cut (the ellipse's chord, one column of margin each
// side against rounding: the per-lane test decides exactly).
struct RowSpans {
  HWY_ALIGN float cut[kTileSize];
  HWY_ALIGN float dy[kTileSize];
  HWY_ALIGN std::int32_t lo[kTileSize];
  HWY_ALIGN std::int32_t hi[kTileSize];
};

// Fills `spans` for the Gaussian (u, v, conic A, B, C) whose row cutoffs are
// min(δ, 2 (ln_peak − floors.ln_floor[r]) + margin). With count_skipped, returns the soft-MIP terms the
// cutoffs drop: pixel centres of the tile inside q <= δ but outside q <= cut[r].
inline std::int64_t row_spans(const TileFrame& f, const RowFloors& floors, const PackedSplat& g, float ln_peak,
                              bool count_skipped, RowSpans& spans) {
  const hn::ScalableTag<float> d;
  const hn::RebindToSigned<decltype(d)> di;
  const int N = static_cast<int>(hn::Lanes(d));
  const float u = g.u, v = g.v, A = g.A, B = g.B;
  const auto vA = hn::Set(d, A), vdet = hn::Set(d, g.det), vinv_A = hn::Set(d, g.inv_A);
  const auto delta = hn::Set(d, f.k.cutoff), zero = hn::Zero(d), one = hn::Set(d, 1.0f);
  const auto last_col = hn::Set(d, static_cast<float>(f.width - 1)), height = hn::Set(d, static_cast<float>(f.height));
  const auto dy0 = hn::Set(d, static_cast<float>(f.y0) + 0.5f - v);
  const auto mid0 = hn::Set(d, u - static_cast<float>(f.x0) - 0.5f), B_over_A = hn::Set(d, B * g.inv_A);
  const auto peak2 = hn::Set(d, 2.0f * ln_peak), margin = hn::Set(d, kCutoffMargin);
  const auto widen = hn::Set(d, 1.0f + 1e-3f);
  // Pixel centres of each row inside q <= x (no margin); 0 where x <= 0 or the row misses.
  auto inside = [&](auto row_ok, auto dy2det, auto mid, auto x) {
    const auto D = hn::NegMulAdd(one, dy2det, hn::Mul(vA, x));
    const auto root = hn::Mul(hn::Sqrt(hn::Max(D, zero)), vinv_A);
    const auto c0 = hn::Max(hn::Ceil(hn::Sub(mid, root)), zero);
    const auto c1 = hn::Min(hn::Floor(hn::Add(mid, root)), last_col);
    const auto ok = hn::And(row_ok, hn::And(hn::Ge(D, zero), hn::Gt(x, zero)));
    return hn::IfThenElseZero(ok, hn::Max(hn::Add(hn::Sub(c1, c0), one), zero));
  };
  auto skipped = zero;
  for (int r0 = 0; r0 < kTileSize; r0 += N) {
    const auto row = hn::Iota(d, static_cast<float>(r0));
    const auto row_ok = hn::Lt(row, height);
    const auto dy = hn::Add(dy0, row);
    const auto cut =
        hn::Min(delta, hn::Add(hn::Sub(peak2, hn::Mul(hn::Set(d, 2.0f), hn::Load(d, floors.ln_floor + r0))), margin));
    const auto dy2det = hn::Mul(hn::Mul(dy, dy), vdet);
    const auto mid = hn::NegMulAdd(B_over_A, dy, mid0);  // chord centre: u − B dy / A, tile-local
    const auto D = hn::NegMulAdd(one, dy2det, hn::Mul(vA, hn::Mul(cut, widen)));
    const auto root = hn::Mul(hn::Sqrt(hn::Max(D, zero)), vinv_A);
    // Clamped in float so the int conversion never sees an out-of-range value.
    const auto lo = hn::Min(hn::Max(hn::Sub(hn::Ceil(hn::Sub(mid, root)), one), zero), last_col);
    const auto hi = hn::Max(hn::Min(hn::Add(hn::Floor(hn::Add(mid, root)), one), last_col), hn::Set(d, -1.0f));
    const auto ok = hn::And(row_ok, hn::And(hn::Ge(D, zero), hn::Gt(cut, zero)));
    hn::Store(cut, d, spans.cut + r0);
    hn::Store(dy, d, spans.dy + r0);
    hn::Store(hn::ConvertTo(di, lo), di, spans.lo + r0);
    hn::Store(hn::ConvertTo(di, hn::IfThenElse(ok, hi, hn::Set(d, -1.0f))), di, spans.hi + r0);
    if (count_skipped) {
      const auto dropped = hn::Sub(inside(row_ok, dy2det, mid, delta), inside(row_ok, dy2det, mid, cut));
      skipped = hn::Add(skipped, hn::IfThenElseZero(hn::Lt(cut, delta), dropped));
    }
  }
  return count_skipped ? static_cast<std::int64_t>(hn::GetLane(hn::SumOfLanes(d, skipped))) : 0;
}

// Whole-tile test, before any per-row work, for the kRefreshEvery entries from i0
// at once (SIMD across Gaussians): bit j is set when entry i0 + j may reach one of
// the tile's pixels within its loosest (floor-limited) cutoff, whose peak is
// ln_add + ln a. That is, the smallest q = dᵀ Σ⁻¹ d over the tile's pixel centres
// (the rectangle they span; 0 when it holds the centre) is within the cutoff; q is
// convex, so off the rectangle its minimum lies on an edge, where it is a 1D
// quadratic minimized at a clamped vertex. The minimum is compared with the
// cutoff widened by kRejectSlack, so rounding never drops a Gaussian that a lane's
// own test would keep.
constexpr float kRejectSlack = 1.0f + 1e-3f;
HWY_INLINE std::uint32_t batch_hits(const TileFrame& f, const RowFloors& floors, const TileGaussians& gs, int i0,
                                    float ln_add) {
  const hn::ScalableTag<float> d;
  const int N = static_cast<int>(hn::Lanes(d));
  constexpr int kSlots = hn::MaxLanes(d) > kRefreshEvery ? static_cast<int>(hn::MaxLanes(d)) : kRefreshEvery;
  const int n = std::min(kRefreshEvery, gs.count - i0);
  HWY_ALIGN float u[kSlots] = {}, v[kSlots] = {}, A[kSlots] = {}, B[kSlots] = {}, C[kSlots] = {};
  HWY_ALIGN float inv_A[kSlots] = {}, inv_C[kSlots] = {}, ln_amp[kSlots] = {};
  for (int j = 0; j < n; ++j) {
    const PackedSplat& g = gs[i0 + j];
    u[j] = g.u, v[j] = g.v, A[j] = g.A, B[j] = g.B, C[j] = g.C;
    inv_A[j] = g.inv_A, inv_C[j] = g.inv_C, ln_amp[j] = g.ln_amp;
  }
  const auto zero = hn::Zero(d), two = hn::Set(d, 2.0f);
  const auto px = hn::Set(d, static_cast<float>(f.x0) + 0.5f), py = hn::Set(d, static_cast<float>(f.y0) + 0.5f);
  const auto w1 = hn::Set(d, static_cast<float>(f.width - 1)), h1 = hn::Set(d, static_cast<float>(f.height - 1));
  const auto delta = hn::Set(d, f.k.cutoff), floor2 = hn::Set(d, 2.0f * (ln_add - floors.tile_floor));
  std::uint32_t bits = 0;
  for (int j0 = 0; j0 < kRefreshEvery; j0 += N) {
    const auto vA = hn::Load(d, A + j0), vB = hn::Load(d, B + j0), vC = hn::Load(d, C + j0);
    const auto xa = hn::Sub(px, hn::Load(d, u + j0)), xb = hn::Add(xa, w1);
    const auto ya = hn::Sub(py, hn::Load(d, v + j0)), yb = hn::Add(ya, h1);
    auto q = [&](auto x, auto y) {
      return hn::MulAdd(hn::MulAdd(vA, x, hn::Mul(two, hn::Mul(vB, y))), x, hn::Mul(vC, hn::Mul(y, y)));
    };
    const auto minus_B_inv_A = hn::Neg(hn::Mul(vB, hn::Load(d, inv_A + j0)));
    const auto minus_B_inv_C = hn::Neg(hn::Mul(vB, hn::Load(d, inv_C + j0)));
    auto along_x = [&](auto y) {
      return q(hn::Min(hn::Max(hn::Mul(minus_B_inv_A, y), xa), xb), y);
    };  // edge at fixed y
    auto along_y = [&](auto x) {
      return q(x, hn::Min(hn::Max(hn::Mul(minus_B_inv_C, x), ya), yb));
    };  // edge at fixed x
    const auto edges = hn::Min(hn::Min(along_x(ya), along_x(yb)), hn::Min(along_y(xa), along_y(xb)));
    const auto inside =
        hn::And(hn::And(hn::Le(xa, zero), hn::Ge(xb, zero)), hn::And(hn::Le(ya, zero), hn::Ge(yb, zero)));
    const auto min_q = hn::IfThenZeroElse(inside, edges);
    // The tile's loosest cutoff: min(δ, 2 (ln_peak − tile floor) + margin).
    const auto cut =
        hn::Min(delta, hn::Add(hn::MulAdd(two, hn::Load(d, ln_amp + j0), floor2), hn::Set(d, kCutoffMargin)));
    const auto hit = hn::And(hn::And(hn::Gt(cut, zero), hn::Le(min_q, hn::Mul(cut, hn::Set(d, kRejectSlack)))),
                             hn::Lt(hn::Iota(d, static_cast<float>(j0)), hn::Set(d, static_cast<float>(n))));
    std::uint8_t mask_bits[8] = {};
    hn::StoreMaskBits(d, hit, mask_bits);
    std::uint32_t lane_bits = 0;
    for (int byte = 0; byte < (N + 7) / 8 && byte < 4; ++byte)
      lane_bits |= static_cast<std::uint32_t>(mask_bits[byte]) << (8 * byte);
    bits |= lane_bits << j0;
  }
  return bits & ((1u << kRefreshEvery) - 1u);
}

// Calls body(at, dy, dx, q, mask) for every SIMD chunk of every row of the
// Gaussian's spans: `at` its first pixel (r·16 + c), dx and dy the offsets of its
// pixel centres from the Gaussian's centre, q their Mahalanobis distance, mask the
// lanes inside the row's cutoff and the image; chunks with no such lane are not
// visited.
template <class Body>
HWY_INLINE void for_each_chunk(const TileFrame& f, const RowSpans& spans, const PackedSplat& g, Body&& body) {
  const float u = g.u, A = g.A, B = g.B, C = g.C;
  const hn::ScalableTag<float> d;
  const int lanes = std::min(static_cast<int>(hn::Lanes(d)), kTileSize);  // chunks never cross the tile's 16 columns
  const auto iota = hn::Iota(d, 0.5f);
  const auto vA = hn::Set(d, A), v2B = hn::Set(d, 2.0f * B), vC = hn::Set(d, C);
  const auto x_minus_u = hn::Set(d, static_cast<float>(f.x0) - u);
  for (int r = 0; r < f.height; ++r) {
    const int lo = spans.lo[r], hi = spans.hi[r];
    if (hi < lo) continue;
    const auto vcut = hn::Set(d, spans.cut[r]);
    const auto vdy = hn::Set(d, spans.dy[r]);
    const auto Cdy2 = hn::Mul(vC, hn::Mul(vdy, vdy));
    const auto twoBdy = hn::Mul(v2B, vdy);
    for (int c = (lo / lanes) * lanes; c <= hi; c += lanes) {
      const auto dx = hn::Add(iota, hn::Add(x_minus_u, hn::Set(d, static_cast<float>(c))));
      const auto q = hn::MulAdd(hn::MulAdd(vA, dx, twoBdy), dx, Cdy2);
      auto mask = hn::Le(q, vcut);
      if (c + lanes > f.width)
        mask = hn::And(mask, hn::Lt(hn::Iota(d, static_cast<float>(c)), hn::Set(d, static_cast<float>(f.width))));
      if (hn::AllFalse(d, mask)) continue;
      body(r * kTileSize + c, vdy, dx, q, mask);
    }
  }
}

// Pass 1, both modes: lm = ln of the largest g = a e^{-q/2} over the terms with
// q <= δ at each pixel, exact, in the log domain (ln g = ln a − q/2: no exp).
// Gaussians that cannot raise a pixel are culled by the running row floors. With
// kArgmax, arg (tile-local) gets the id of the Gaussian that raised each pixel
// last: its argmax, the first in list order among equals (−1: none or the floor).
template <bool kArgmax>
void LogMaxPass(const TileFrame& f, const TileGaussians& gs, float* lm, std::int32_t* arg) {
  const hn::ScalableTag<float> d;
  const hn::RebindToSigned<decltype(d)> di;
  const auto minus_half = hn::Set(d, -0.5f);
  RowFloors floors;
  RowSpans spans;
  std::uint32_t hits = 0;
  for (int i = 0; i < gs.count; ++i) {
    const PackedSplat& g = gs[i];
    const float amp = g.amp, ln_amp = g.ln_amp;
    if (i % kRefreshEvery == 0) {
      floors.from_log_max(f, lm);
      if (floors.none_after(f, amp, 0.0f)) break;
      hits = batch_hits(f, floors, gs, i, 0.0f);
    }
    if (!((hits >> (i % kRefreshEvery)) & 1u)) continue;  // most miss
    row_spans(f, floors, g, ln_amp, false, spans);
    const auto vln_amp = hn::Set(d, ln_amp);
    [[maybe_unused]] const auto id = hn::Set(di, static_cast<std::int32_t>(gs.ids[i]));
    for_each_chunk(f, spans, g, [&](int at, auto, auto, auto q, auto mask) {
      const auto old = hn::Load(d, lm + at);
      if constexpr (kArgmax) {
        const auto value = hn::MulAdd(minus_half, q, vln_amp);
        const auto raised = hn::And(mask, hn::Gt(value, old));
        hn::Store(hn::IfThenElse(raised, value, old), d, lm + at);
        hn::Store(hn::IfThenElse(hn::RebindMask(di, raised), id, hn::Load(di, arg + at)), di, arg + at);
      } else {
        hn::Store(hn::IfThenElse(mask, hn::Max(old, hn::MulAdd(minus_half, q, vln_amp)), old), d, lm + at);
      }
    });
  }
}

// Pass 2, soft-MIP: with every pixel's final M = β max g known, the online softmax
// of §9.3 needs no rescaling: S = Σ e^{βg − M}, W = Σ e^{βg − M} g. The floors are
// final from the first Gaussian, so the skip rule culls as much as it ever can.
std::int64_t SoftPass(const TileFrame& f, const TileGaussians& gs, const float* M, float* S, float* W) {
  const hn::ScalableTag<float> d;
  // In base 2: g = a 2^{−q log2e / 2}, e = 2^{β' g − M'} with β' = β log2e, M' = M log2e.
  const auto minus_half_log2e = hn::Set(d, -0.5f * kLog2e);
  const auto beta2 = hn::Set(d, f.k.beta * kLog2e);
  const float ln_beta = fast_log(f.k.beta);
  const bool exact = !(f.k.skip_log_weight > 0.0f);
  const bool count_skipped = f.k.count_skipped && !exact;
  RowFloors floors;
  floors.from_soft_max(f, M, exact);
  HWY_ALIGN float M2[kTileSize * kTileSize];
  times_log2e(M, M2);
  RowSpans spans;
  std::int64_t skipped = 0;
  std::uint32_t hits = 0;
  for (int i = 0; i < gs.count; ++i) {
    const PackedSplat& g = gs[i];
    const float amp = g.amp;
    if (i % kRefreshEvery == 0) {
      if (floors.none_after(f, amp, ln_beta)) {
        if (count_skipped) {  // what the rest would have contributed
          for (int j = i; j < gs.count; ++j) {
            skipped += row_spans(f, floors, gs[j], -std::numeric_limits<float>::infinity(), true, spans);
          }
        }
        break;
      }
      // Counting skipped terms needs every Gaussian's spans.
      hits = count_skipped ? ~0u : batch_hits(f, floors, gs, i, ln_beta);
    }
    if (!((hits >> (i % kRefreshEvery)) & 1u)) continue;  // most miss
    const float ln_peak = ln_beta + g.ln_amp;
    skipped += row_spans(f, floors, g, ln_peak, count_skipped, spans);
    const auto vamp = hn::Set(d, amp);
    for_each_chunk(f, spans, g, [&](int at, auto, auto, auto q, auto mask) {
      const auto gk = hn::Mul(vamp, Exp2NonPositive(d, hn::Mul(minus_half_log2e, q)));
      const auto e = hn::IfThenElseZero(mask, Exp2NonPositive(d, hn::MulSub(beta2, gk, hn::Load(d, M2 + at))));
      hn::Store(hn::Add(hn::Load(d, S + at), e), d, S + at);
      hn::Store(hn::MulAdd(e, gk, hn::Load(d, W + at)), d, W + at);
    });
  }
  return skipped;
}

void ForwardTile(const TileFrame& f, const TileGaussians& gs, float* m_out, float* S_out, float* I_out,
                 std::int32_t* arg_out, std::int64_t* skipped_out) {
  const hn::ScalableTag<float> d;
  const int N = static_cast<int>(hn::Lanes(d));
  constexpr float kInf = std::numeric_limits<float>::infinity();
  // Tile-local rows of 16; the padding columns past the image hold +∞ in lm and M
  // (they never lower a row's floor) and are never written by the passes.
  HWY_ALIGN float lm[kTileSize * kTileSize], M[kTileSize * kTileSize], S[kTileSize * kTileSize],
      W[kTileSize * kTileSize];
  // Hard mode: the floor, when there is one, is each pixel's first term, ln b in the
  // log max (soft mode takes the max with it outside: splat_cpu.cpp).
  const bool hard_floor = f.floor != nullptr && !f.k.soft();
  for (int r = 0; r < kTileSize; ++r) {
    for (int c = 0; c < kTileSize; ++c) {
      float init = c < f.width ? -kInf : kInf;
      if (hard_floor && c < f.width && r < f.height) {
        const float b = f.floor[static_cast<std::size_t>(f.y0 + r) * f.stride + f.x0 + c];
        if (b > 0.0f) init = std::log(b);
      }
      lm[r * kTileSize + c] = init;
    }
  }
  HWY_ALIGN std::int32_t arg[kTileSize * kTileSize];
  if (arg_out != nullptr) {
    std::fill(arg, arg + kTileSize * kTileSize, -1);
    LogMaxPass<true>(f, gs, lm, arg);
  } else {
    LogMaxPass<false>(f, gs, lm, nullptr);
  }
  // M = β e^{lm} (soft) or e^{lm} (hard): the largest (β) g; +∞ where nothing reaches
  // the pixel (lm = −∞), so such pixels never lower a soft row floor.
  const auto scale = hn::Set(d, f.k.soft() ? f.k.beta : 1.0f);
  for (int at = 0; at < kTileSize * kTileSize; at += N) {
    const auto x = hn::Load(d, lm + at);
    const auto touched = hn::Gt(x, hn::Set(d, -kInf));
    hn::Store(hn::IfThenElse(touched, hn::Mul(scale, ExpNonPositive(d, x)), hn::Set(d, kInf)), d, M + at);
  }
  if (f.k.soft()) {
    std::fill(S, S + kTileSize * kTileSize, 0.0f);
    std::fill(W, W + kTileSize * kTileSize, 0.0f);
    *skipped_out += SoftPass(f, gs, M, S, W);
  }
  for (int r = 0; r < f.height; ++r) {
    const std::size_t row = static_cast<std::size_t>(f.y0 + r) * f.stride + f.x0;
    for (int c = 0; c < f.width; ++c) {
      const int at = r * kTileSize + c;
      const bool touched = lm[at] > -kInf;
      m_out[row + c] = touched ? M[at] : -kInf;
      if (arg_out != nullptr) arg_out[row + c] = arg[at];
      if (f.k.soft()) {
        S_out[row + c] = S[at];
        I_out[row + c] = S[at] > 0.0f ? W[at] / S[at] : 0.0f;
      } else {
        S_out[row + c] = touched ? 1.0f : 0.0f;
        I_out[row + c] = touched ? M[at] : 0.0f;
      }
    }
  }
}

// A tile's copy of the forward's per-pixel state the backward reads: m, 1/S, I
// and dL/dI (all 0 where nothing touched the pixel), and m in base 2.
struct BackwardPixels {
  HWY_ALIGN float m[kTileSize * kTileSize];
  HWY_ALIGN float inv_S[kTileSize * kTileSize];
  HWY_ALIGN float I[kTileSize * kTileSize];
  HWY_ALIGN float G[kTileSize * kTileSize];
  HWY_ALIGN float m2[kTileSize * kTileSize];
};

HWY_INLINE void LoadBackwardPixels(const TileFrame& f, const float* m_in, const float* S_in, const float* I_in,
                                   const float* dL_dI_in, BackwardPixels& p) {
  std::fill(p.m, p.m + kTileSize * kTileSize, 0.0f);
  std::fill(p.inv_S, p.inv_S + kTileSize * kTileSize, 0.0f);
  std::fill(p.I, p.I + kTileSize * kTileSize, 0.0f);
  std::fill(p.G, p.G + kTileSize * kTileSize, 0.0f);
  for (int r = 0; r < f.height; ++r) {
    const std::size_t row = static_cast<std::size_t>(f.y0 + r) * f.stride + f.x0;
    for (int c = 0; c < f.width; ++c) {
      const int at = r * kTileSize + c;
      if (S_in[row + c] > 0.0f) {
        p.m[at] = m_in[row + c];
        p.inv_S[at] = 1.0f / S_in[row + c];
        p.I[at] = I_in[row + c];
        p.G[at] = dL_dI_in[row + c];
      }
    }
  }
  times_log2e(p.m, p.m2);
}

// The forward's skip rule on the same final m, so exactly the terms the forward
// summed are differentiated. Untouched pixels (no gradient flows through them) do
// not lower a row's floor.
HWY_INLINE RowFloors BackwardFloors(const TileFrame& f, const BackwardPixels& p) {
  RowFloors floors;
  HWY_ALIGN float m_floor[kTileSize * kTileSize];
  for (int at = 0; at < kTileSize * kTileSize; ++at) {
    m_floor[at] = p.inv_S[at] > 0.0f ? p.m[at] : std::numeric_limits<float>::infinity();
  }
  floors.from_soft_max(f, m_floor, !(f.k.skip_log_weight > 0.0f));
  return floors;
}

// One Gaussian's six gradient sums (dL/du, dL/dv, dL/dA, dL/dB, dL/dC, dL/da) over the
// pixels of its row spans, in base 2 as the forward: G = 2^{−q log2e / 2},
// e^{βg − m} = 2^{β' g − m'}.
HWY_INLINE void GaussianGrads(const TileFrame& f, const BackwardPixels& p, const PackedSplat& g, const RowSpans& spans,
                              float* out) {
  const hn::ScalableTag<float> d;
  const auto beta = hn::Set(d, f.k.beta);
  const auto minus_half = hn::Set(d, -0.5f);
  const auto one = hn::Set(d, 1.0f);
  const auto two = hn::Set(d, 2.0f);
  const auto minus_half_log2e = hn::Set(d, -0.5f * kLog2e);
  const auto beta2 = hn::Set(d, f.k.beta * kLog2e);
  const auto vA = hn::Set(d, g.A), vB = hn::Set(d, g.B), vC = hn::Set(d, g.C), vamp = hn::Set(d, g.amp);
  auto su = hn::Zero(d), sv = hn::Zero(d), sA = hn::Zero(d), sB = hn::Zero(d), sC = hn::Zero(d), samp = hn::Zero(d);
  for_each_chunk(f, spans, g, [&](int at, auto vdy, auto dx, auto q, auto mask) {
    const auto dL_dI = hn::Load(d, p.G + at);
    mask = hn::And(mask, hn::Ne(dL_dI, hn::Zero(d)));
    if (hn::AllFalse(d, mask)) return;
    const auto Gk = Exp2NonPositive(d, hn::Mul(minus_half_log2e, q));
    const auto gk = hn::Mul(vamp, Gk);
    // dI/dg = w (1 + β (g − I)), w = e^{βg − m} / S
    const auto w =
        hn::Mul(Exp2NonPositive(d, hn::MulSub(beta2, gk, hn::Load(d, p.m2 + at))), hn::Load(d, p.inv_S + at));
    const auto dI_dg = hn::Mul(w, hn::MulAdd(beta, hn::Sub(gk, hn::Load(d, p.I + at)), one));
    const auto dL_dg = hn::IfThenElseZero(mask, hn::Mul(dL_dI, dI_dg));
    samp = hn::MulAdd(dL_dg, Gk, samp);
    const auto dL_dq = hn::Mul(hn::Mul(minus_half, dL_dg), gk);  // d(a e^{-q/2})/dq = −½ g
    sA = hn::MulAdd(dL_dq, hn::Mul(dx, dx), sA);
    sB = hn::MulAdd(dL_dq, hn::Mul(two, hn::Mul(dx, vdy)), sB);
    sC = hn::MulAdd(dL_dq, hn::Mul(vdy, vdy), sC);
    // dq/du = −2 (A dx + B dy), dq/dv = −2 (B dx + C dy)
    su = hn::MulAdd(dL_dq, hn::MulAdd(vA, dx, hn::Mul(vB, vdy)), su);
    sv = hn::MulAdd(dL_dq, hn::MulAdd(vB, dx, hn::Mul(vC, vdy)), sv);
  });
  out[0] = -2.0f * hn::GetLane(hn::SumOfLanes(d, su));
  out[1] = -2.0f * hn::GetLane(hn::SumOfLanes(d, sv));
  out[2] = hn::GetLane(hn::SumOfLanes(d, sA));
  out[3] = hn::GetLane(hn::SumOfLanes(d, sB));
  out[4] = hn::GetLane(hn::SumOfLanes(d, sC));
  out[5] = hn::GetLane(hn::SumOfLanes(d, samp));
}

void BackwardTile(const TileFrame& f, const TileGaussians& gs, const float* m_in, const float* S_in, const float* I_in,
                  const float* dL_dI_in, float* grads) {
  BackwardPixels pixels;
  LoadBackwardPixels(f, m_in, S_in, I_in, dL_dI_in, pixels);
  const RowFloors floors = BackwardFloors(f, pixels);
  const float ln_beta = fast_log(f.k.beta);
  RowSpans spans;
  std::uint32_t hits = 0;
  for (int i = 0; i < gs.count; ++i) {
    const PackedSplat& g = gs[i];
    float* out = grads + 6 * static_cast<std::size_t>(i);
    if (i % kRefreshEvery == 0) {
      if (floors.none_after(f, g.amp, ln_beta)) {  // as the forward's early stop
        std::fill(out, grads + 6 * static_cast<std::size_t>(gs.count), 0.0f);
        break;
      }
      hits = batch_hits(f, floors, gs, i, ln_beta);
    }
    if (!((hits >> (i % kRefreshEvery)) & 1u)) {
      std::fill(out, out + 6, 0.0f);
      continue;
    }
    row_spans(f, floors, g, ln_beta + g.ln_amp, false, spans);
    GaussianGrads(f, pixels, g, spans, out);
  }
}

HWY_INLINE void OneTileBands(const EllipseBands& e, int ty0, int rows, int x0, int x1, std::int16_t* tx0_out,
                             std::int16_t* tx1_out) {
  const hn::ScalableTag<float> d;
  const hn::RebindToSigned<decltype(d)> di;
  const int N = static_cast<int>(hn::Lanes(d));
  const auto u = hn::Set(d, e.u), slope = hn::Set(d, e.slope), k1 = hn::Set(d, e.k1), k2 = hn::Set(d, e.k2);
  const auto dy_right = hn::Set(d, e.dy_right), dy_left = hn::Set(d, -e.dy_right), zero = hn::Zero(d);
  const auto tile = hn::Set(d, static_cast<float>(kTileSize)), inv_tile = hn::Set(d, 1.0f / kTileSize);
  const auto lowest = hn::Set(d, -2.0f), highest = hn::Set(d, static_cast<float>(1 << 30));
  const auto x0f = hn::Set(d, static_cast<float>(x0)), x1f = hn::Set(d, static_cast<float>(x1));
  for (int b0 = 0; b0 < rows; b0 += N) {
    const auto band = hn::Iota(d, static_cast<float>(b0));
    const auto ya = hn::Sub(hn::Mul(hn::Add(band, hn::Set(d, static_cast<float>(ty0))), tile), hn::Set(d, e.v));
    const auto yb = hn::Add(ya, tile);
    // The chords at the band's two edges: x = u + slope y ± √(k1 − k2 y²).
    const auto Da = hn::NegMulAdd(hn::Mul(k2, ya), ya, k1), Db = hn::NegMulAdd(hn::Mul(k2, yb), yb, k1);
    const auto ra = hn::Sqrt(hn::Max(Da, zero)), rb = hn::Sqrt(hn::Max(Db, zero));
    const auto ma = hn::MulAdd(slope, ya, u), mb = hn::MulAdd(slope, yb, u);
    const auto oka = hn::Ge(Da, zero), okb = hn::Ge(Db, zero);
    // Right edge: at the rightmost point's dy clamped to the band; left likewise.
    const auto above_r = hn::Lt(dy_right, ya), below_r = hn::Gt(dy_right, yb);
    const auto above_l = hn::Lt(dy_left, ya), below_l = hn::Gt(dy_left, yb);
    auto right = hn::IfThenElse(above_r, hn::Add(ma, ra),
                                hn::IfThenElse(below_r, hn::Add(mb, rb), hn::Add(u, hn::Set(d, e.x_right))));
    auto left = hn::IfThenElse(above_l, hn::Sub(ma, ra),
                               hn::IfThenElse(below_l, hn::Sub(mb, rb), hn::Sub(u, hn::Set(d, e.x_right))));
    const auto ok_r = hn::Or(hn::And(above_r, oka), hn::Or(hn::And(below_r, okb), hn::Not(hn::Or(above_r, below_r))));
    const auto ok_l = hn::Or(hn::And(above_l, oka), hn::Or(hn::And(below_l, okb), hn::Not(hn::Or(above_l, below_l))));
    const auto hit = hn::And(hn::And(ok_r, ok_l), hn::Lt(band, hn::Set(d, static_cast<float>(rows))));
    // Pixel columns ⌈left − pad − ½⌉ .. ⌊right + pad − ½⌋, then tiles within [x0, x1].
    const auto half_pad = hn::Set(d, e.pad + 0.5f);
    const auto c0 = hn::Ceil(hn::Min(hn::Max(hn::Sub(left, half_pad), lowest), highest));
    const auto c1 =
        hn::Floor(hn::Min(hn::Max(hn::Sub(hn::Add(right, hn::Set(d, e.pad)), hn::Set(d, 0.5f)), lowest), highest));
    const auto t0 = hn::Max(x0f, hn::Floor(hn::Mul(hn::Max(c0, zero), inv_tile)));
    const auto t1 = hn::Min(x1f, hn::Floor(hn::Mul(c1, inv_tile)));
    const auto none = hn::Not(hn::And(hit, hn::And(hn::Le(c0, c1), hn::Le(t0, t1))));
    HWY_ALIGN std::int32_t lo[hn::MaxLanes(d)], hi[hn::MaxLanes(d)];
    hn::Store(hn::ConvertTo(di, hn::IfThenElse(none, zero, t0)), di, lo);
    hn::Store(hn::ConvertTo(di, hn::IfThenElse(none, hn::Set(d, -1.0f), t1)), di, hi);
    for (int i = 0; i < N && b0 + i < rows; ++i) {
      tx0_out[b0 + i] = static_cast<std::int16_t>(lo[i]);
      tx1_out[b0 + i] = static_cast<std::int16_t>(hi[i]);
    }
  }
}

void TileBands(const BandJob* jobs, std::size_t count) {
  for (std::size_t i = 0; i < count; ++i) {
    const BandJob& j = jobs[i];
    OneTileBands(j.e, j.ty0, j.rows, j.x0, j.x1, j.tx0, j.tx1);
  }
}

}  // namespace HWY_NAMESPACE
}  // namespace hisnegs::splat::detail
HWY_AFTER_NAMESPACE();

#if HWY_ONCE
namespace hisnegs::splat::detail {

HWY_EXPORT(ForwardTile);
HWY_EXPORT(BackwardTile);
HWY_EXPORT(TileBands);

void tile_bands(const BandJob* jobs, std::size_t count) { HWY_DYNAMIC_DISPATCH(TileBands)(jobs, count); }

void forward_tile(const TileFrame& frame, const TileGaussians& gaussians, float* m, float* S, float* I,
                  std::int32_t* argmax, std::int64_t* skipped) {
  HWY_DYNAMIC_DISPATCH(ForwardTile)(frame, gaussians, m, S, I, argmax, skipped);
}

void backward_tile(const TileFrame& frame, const TileGaussians& gaussians, const float* m, const float* S,
                   const float* I, const float* dL_dI, float* grads) {
  HWY_DYNAMIC_DISPATCH(BackwardTile)(frame, gaussians, m, S, I, dL_dI, grads);
}

}  // namespace hisnegs::splat::detail
#endif
