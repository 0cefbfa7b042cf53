// SPDX-License-Identifier: Apache-2.0
// Per-Gaussian math of soft/hard-MIP splatting shared by the double reference,
// the TBB and the CUDA back ends (report §2.2, Eq. 2-8): EWA projection of one
// Gaussian to a 2D conic, its pixel footprint, the 2D value and the exact backward
// of all of it to the 11 parameters. Templated on the scalar, no allocation.
//
// Definitions (the report leaves these open; docs/file-formats.md "Rendering"):
// - A Gaussian is visible when near <= z_cam(μ) <= far; otherwise it contributes
//   nothing (culled by its centre, as 3DGS does).
// - Pixel (c, r) is evaluated at its centre p = (c + 0.5, r + 0.5) (CONVENTIONS).
// - It touches the pixels with (p − μ2D)ᵀ Σ2D⁻¹ (p − μ2D) <= δ; soft-MIP (Eq. 8) runs
//   over exactly these Gaussians (report §9.3, "each Gaussian overlapping the pixel"),
//   and a pixel no Gaussian touches is 0.
// - Σ2D = J W Σ Wᵀ Jᵀ + low_pass · I (low_pass 0 by default, as the report).
#pragma once

#include <cmath>

#include "gmf/core/aggregation.hpp"
#include "gmf/core/gaussian_math.hpp"
#include "gmf/core/hd.hpp"
#include "gmf/core/param_layout.hpp"

namespace hisnegs::splat {

// A pinhole view in the form the kernels use (CONVENTIONS "Cameras").
template <class T>
struct ViewParams {
  T R[9];  // world -> camera rotation, row-major
  T t[3];  // translation: p_cam = R p_world + t
  T fx, fy, cx, cy;
  T near_z, far_z;
  int width, height;
};

// Side of the square pixel tiles every rasterizer (CPU and CUDA) bins Gaussians into.
inline constexpr int kTileSize = 16;

// How a pixel's terms combine: gmf::Aggregation, the one policy of the fit and the
// splatting (gmf/core/aggregation.hpp): soft-MIP = kSoftmax (Eq. 8), hard MIP =
// kMax; kSum is not a MIP and no renderer takes it (SplatOptions::validate).
using MipMode = gmf::Aggregation;

// What one frame is rendered with: the one settings struct that travels from
// SplatOptions (config) through the renderer to the tile kernels of both back ends
// (C++17, so nvcc can compile it). β changes during training.
struct KernelSettings {
  MipMode mode = MipMode::kSoftmax;  // soft-MIP (Eq. 8) or hard MIP (max)
  float beta = 50.0f;             // β
  float cutoff = 16.0f;           // δ
  float low_pass = 0.0f;          // pixels², added to Σ2D's diagonal
  float skip_log_weight = 20.0f;  // skip terms with β a_k < m − this; 0 = never (see SplatOptions)
  // Fill SplatFrameStats::skipped_terms. Both back ends then walk every skipped
  // Gaussian to the end of each tile's list instead of stopping early (the CPU takes
  // about 1.5x its soft-MIP time), so it is off by default.
  bool count_skipped = false;
  HISNEGS_HD bool soft() const { return mode == MipMode::kSoftmax; }
  // Hard mode: the forward keeps each pixel's argmax Gaussian, which the hard
  // backward (the max's subgradient) needs; off for renders that only look.
  bool keep_argmax = false;
};

// One Gaussian as the rasterizer sees it.
template <class T>
struct Splat2D {
  T u, v;                 // μ2D, pixels (Eq. 5)
  T con_a, con_b, con_c;  // conic Σ2D⁻¹ = [[a, b], [b, c]]
  T amplitude;            // a_k = sigmoid(ℓ)
  T half_w, half_h;       // half extents of the δ ellipse's bounding box, pixels
  T depth;                // z_cam of μ
  bool visible;
};

// Intermediates kept from the forward for the backward of one Gaussian.
template <class T>
struct ProjectionCache {
  T mean_cam[3];
  T cov2d[3];  // Σ2D entries (a, b, c) including low_pass
};

// W = J R (2x3, row-major), J the pinhole Jacobian of Eq. 4 at μ_cam; also J's
// entries (j00, j02, j11, j12), which the backward needs.
template <class T>
HISNEGS_HD void projection_jacobian(const ViewParams<T>& view, const T mc[3], T W[6], T j[4]) {
  const T iz = T(1) / mc[2];
  j[0] = view.fx * iz;
  j[1] = -view.fx * mc[0] * iz * iz;
  j[2] = view.fy * iz;
  j[3] = -view.fy * mc[1] * iz * iz;
  for (int c = 0; c < 3; ++c) {
    W[c] = j[0] * view.R[c] + j[1] * view.R[6 + c];
    W[3 + c] = j[2] * view.R[3 + c] + j[3] * view.R[6 + c];
  }
}

// Eq. 2-6: projects Gaussian `p` (11 parameters, gmf::GaussianParam order) into `view`.
// `cutoff` is δ. Fills `cache` when not null.
template <class T>
HISNEGS_HD Splat2D<T> project_gaussian(const T p[gmf::kGaussianParamCount], const ViewParams<T>& view, T cutoff,
                                       T low_pass, ProjectionCache<T>* cache = nullptr) {
  using std::sqrt;
  Splat2D<T> s{};
  s.visible = false;
  T mc[3];
  for (int r = 0; r < 3; ++r) {
    mc[r] = view.R[3 * r] * p[gmf::kMeanX] + view.R[3 * r + 1] * p[gmf::kMeanY] + view.R[3 * r + 2] * p[gmf::kMeanZ] +
            view.t[r];
  }
  s.depth = mc[2];
  if (!(mc[2] >= view.near_z && mc[2] <= view.far_z)) return s;
  gmf::GaussianFrame<T> f;
  gmf::prepare_gaussian(p, f);
  T cov[9];
  gmf::world_covariance(f, cov);
  T W[6], j[4];
  projection_jacobian(view, mc, W, j);
  const T iz = T(1) / mc[2];
  // Σ2D = W Σ Wᵀ (Eq. 3, 6) + low_pass I
  T WS[6];
  for (int r = 0; r < 2; ++r) {
    for (int c = 0; c < 3; ++c) {
      WS[3 * r + c] = W[3 * r] * cov[c] + W[3 * r + 1] * cov[3 + c] + W[3 * r + 2] * cov[6 + c];
    }
  }
  const T a = WS[0] * W[0] + WS[1] * W[1] + WS[2] * W[2] + low_pass;
  const T b = WS[0] * W[3] + WS[1] * W[4] + WS[2] * W[5];
  const T c = WS[3] * W[3] + WS[4] * W[4] + WS[5] * W[5] + low_pass;
  const T det = a * c - b * b;
  if (!(det > T(0)) || !(a > T(0))) return s;
  const T inv_det = T(1) / det;
  s.con_a = c * inv_det;
  s.con_b = -b * inv_det;
  s.con_c = a * inv_det;
  s.u = view.fx * mc[0] * iz + view.cx;
  s.v = view.fy * mc[1] * iz + view.cy;
  s.amplitude = f.a;
  // The ellipse dᵀΣ⁻¹d <= δ spans ±sqrt(δ Σ_xx) in u and ±sqrt(δ Σ_yy) in v.
  s.half_w = sqrt(cutoff * a);
  s.half_h = sqrt(cutoff * c);
  s.visible = s.u + s.half_w > T(0) && s.u - s.half_w < T(view.width) && s.v + s.half_h > T(0) &&
              s.v - s.half_h < T(view.height);
  if (cache != nullptr) {
    for (int i = 0; i < 3; ++i) cache->mean_cam[i] = mc[i];
    cache->cov2d[0] = a;
    cache->cov2d[1] = b;
    cache->cov2d[2] = c;
  }
  return s;
}

// The δ ellipse of a Gaussian (dᵀΣ⁻¹d <= δ, conic [[a, b], [b, c]]) row by row,
// for binning Gaussians to the tiles they really touch rather than their bounding
// box's: at dy = y − v its chord is x = u + slope dy ± √(k1 − k2 dy²), with
// slope = −b/a, k1 = δ/a, k2 = det/a². Its rightmost point is (u + x_right,
// v + dy_right), its leftmost the mirror image through (u, v).
template <class T>
struct EllipseRows {
  T u, v, slope, k1, k2, x_right, dy_right;
};

// `widen` (>= 1) scales δ, against rounding.
template <class T>
HISNEGS_HD EllipseRows<T> ellipse_rows(const Splat2D<T>& s, T cutoff, T widen) {
  const T A = s.con_a, B = s.con_b, C = s.con_c, det = A * C - B * B;
  const T delta = cutoff * widen, inv_A = T(1) / A;
  // ∇q ∥ (1, 0) ⇒ b dx + c dy = 0, and q = δ there: dx = √(δ c / det), dy = −b dx / c.
  // sqrt of a float through double (the host's C sqrt) rounds to sqrtf's value: the same on both back ends.
  const T x_right = static_cast<T>(sqrt(delta * C / det));  // NOLINT(performance-type-promotion-in-math-fn)
  return {s.u, s.v, -B * inv_A, delta * inv_A, det * inv_A * inv_A, x_right, -B * x_right / C};
}

// For each band of rows [tile·ty, tile·(ty + 1)] (ty in [ty0, ty1]) that the
// ellipse crosses, calls fn(ty, c0, c1) with the pixel columns [c0, c1] whose
// centres it can reach there (padded by `pad` pixels each side; clamped to
// [−2, 2^30] so huge extents cannot overflow). The ellipse ∩ band is convex, so
// its right edge (concave in y) is largest at the rightmost point's y clamped to
// the band, which is on the band's edge unless the band holds that point: one
// square root per band edge, shared by the bands on both sides.
template <class T, class Fn>
HISNEGS_HD void for_each_ellipse_band(const EllipseRows<T>& e, int ty0, int ty1, int tile, T pad, Fn&& fn) {
  struct Chord {
    T lo, hi;
    bool ok;
  };
  auto chord = [&](int edge) {
    const T dy = T(tile) * T(edge) - e.v, D = e.k1 - e.k2 * dy * dy;
    const T root = D >= T(0) ? static_cast<T>(sqrt(D)) : T(0), mid = e.u + e.slope * dy;
    return Chord{mid - root, mid + root, D >= T(0)};
  };
  auto clamped = [](T x) { return x < T(-2) ? T(-2) : (x > T(1 << 30) ? T(1 << 30) : x); };
  auto ceil_int = [&](T x) {  // via truncation toward zero
    x = clamped(x);
    const int t = static_cast<int>(x);
    return t + (x > T(t) ? 1 : 0);
  };
  auto floor_int = [&](T x) {
    x = clamped(x);
    const int t = static_cast<int>(x);
    return t - (x < T(t) ? 1 : 0);
  };
  Chord top = chord(ty0);
  for (int ty = ty0; ty <= ty1; ++ty) {
    const Chord bottom = chord(ty + 1);
    const T ya = T(tile) * T(ty) - e.v, yb = ya + T(tile);
    bool hit = true;
    T right = e.u + e.x_right, left = e.u - e.x_right;
    if (e.dy_right < ya) {
      right = top.hi, hit = top.ok;
    } else if (e.dy_right > yb) {
      right = bottom.hi, hit = bottom.ok;
    }
    if (-e.dy_right < ya) {
      left = top.lo, hit = hit && top.ok;
    } else if (-e.dy_right > yb) {
      left = bottom.lo, hit = hit && bottom.ok;
    }
    // Columns c with left <= c + ½ <= right: c0 = ⌈left − ½⌉, c1 = ⌊right − ½⌋.
    if (hit) {
      const int c0 = ceil_int(left - pad - T(0.5)), c1 = floor_int(right + pad - T(0.5));
      if (c0 <= c1) fn(ty, c0, c1);
    }
    top = bottom;
  }
}

// Binning, the same for both back ends: which tiles a Gaussian is listed in.
// δ is widened by kBinWiden and the ellipse by kBinPad pixels each side, so
// rounding never drops a tile the kernels' per-pixel test q <= δ would reach.
inline constexpr float kBinWiden = 1.0f + 1e-3f;
inline constexpr float kBinPad = 0.25f;

// Tile rectangle [x0, x1] × [y0, y1] (inclusive, tile units).
struct TileRect {
  int x0, y0, x1, y1;
};

// The tiles of the pixels whose centres can lie in the bounding box of s's ellipse
// (one pixel of margin), clipped to the image; false when that box misses the image
// or s is not finite. Extents are clamped in float before the int conversion, so
// huge ones (e.g. δ = 1e6) cannot overflow.
HISNEGS_HD bool splat_tile_rect(const Splat2D<float>& s, int width, int height, TileRect* rect) {
  using std::ceil;
  using std::floor;
  using std::isfinite;
  if (!isfinite(s.u) || !isfinite(s.v) || !isfinite(s.half_w) || !isfinite(s.half_h)) return false;
  auto pixel = [](float x, int size) {
    return static_cast<int>(x < -1.0f ? -1.0f : (x > static_cast<float>(size) ? static_cast<float>(size) : x));
  };
  auto at_least_0 = [](int v) { return v < 0 ? 0 : v; };
  auto at_most = [](int v, int hi) { return v > hi ? hi : v; };
  const int c0 = at_least_0(pixel(ceil(s.u - s.half_w - 0.5f), width) - 1);
  const int c1 = at_most(pixel(floor(s.u + s.half_w - 0.5f), width) + 1, width - 1);
  const int r0 = at_least_0(pixel(ceil(s.v - s.half_h - 0.5f), height) - 1);
  const int r1 = at_most(pixel(floor(s.v + s.half_h - 0.5f), height) + 1, height - 1);
  if (c0 > c1 || r0 > r1) return false;
  *rect = {c0 / kTileSize, r0 / kTileSize, c1 / kTileSize, r1 / kTileSize};
  return true;
}

// For each tile row ty of `rect` that the ellipse `e` (ellipse_rows(s, δ,
// kBinWiden)) crosses, calls fn(ty, tx0, tx1) with the run of tile columns it
// reaches there (within the rectangle; tx0 <= tx1 not guaranteed: an empty run
// is possible at the image's edge). The CPU back end's SIMD binning
// (detail::tile_bands) computes the same runs eight rows at a time.
template <class Fn>
HISNEGS_HD void for_each_tile_run(const EllipseRows<float>& e, const TileRect& rect, Fn&& fn) {
  for_each_ellipse_band(e, rect.y0, rect.y1, kTileSize, kBinPad, [&](int ty, int c0, int c1) {
    if (c1 < 0) return;
    const int tx0 = (c0 < 0 ? 0 : c0) / kTileSize, tx1 = c1 / kTileSize;
    fn(ty, tx0 > rect.x0 ? tx0 : rect.x0, tx1 < rect.x1 ? tx1 : rect.x1);
  });
}

// The squared 2D Mahalanobis distance of pixel centre (px, py) (Eq. 7's exponent × -2).
template <class T>
HISNEGS_HD T splat_distance(const Splat2D<T>& s, T px, T py) {
  const T dx = px - s.u, dy = py - s.v;
  return s.con_a * dx * dx + T(2) * s.con_b * dx * dy + s.con_c * dy * dy;
}

// Gradient of a loss with respect to one Splat2D's differentiable fields.
template <class T>
struct Splat2DGrad {
  T u = 0, v = 0, con_a = 0, con_b = 0, con_c = 0, amplitude = 0;
};

// Adds to `grad` the contribution of g = a exp(-½ q(px, py)) at one pixel, given dL/dg.
template <class T>
HISNEGS_HD void accumulate_pixel_grad(const Splat2D<T>& s, T px, T py, T dL_dg, Splat2DGrad<T>& grad) {
  using std::exp;
  const T dx = px - s.u, dy = py - s.v;
  const T q = s.con_a * dx * dx + T(2) * s.con_b * dx * dy + s.con_c * dy * dy;
  const T G = exp(T(-0.5) * q);
  grad.amplitude += dL_dg * G;
  const T dL_dq = T(-0.5) * dL_dg * s.amplitude * G;
  grad.con_a += dL_dq * dx * dx;
  grad.con_b += dL_dq * T(2) * dx * dy;
  grad.con_c += dL_dq * dy * dy;
  // q depends on μ through dx = px − u, dy = py − v.
  grad.u += dL_dq * T(-2) * (s.con_a * dx + s.con_b * dy);
  grad.v += dL_dq * T(-2) * (s.con_b * dx + s.con_c * dy);
}

// Backward of project_gaussian: from dL/d(Splat2D) to dL/d(11 parameters), added to
// `out`. `cache` is the one the forward filled. Derivation: conic = Σ2D⁻¹ gives
// dL/dΣ2D = −P Ĝ P (P the conic, Ĝ its gradient as a symmetric matrix); Σ2D = W Σ Wᵀ
// gives dL/dΣ = Wᵀ G W and dL/dW = 2 G W Σ; W = J R and J(μ_cam) of Eq. 4 give the
// mean's second path; Σ = M Mᵀ, M = R(q̂) diag(s) gives dL/dM = 2 (dL/dΣ) M.
template <class T>
HISNEGS_HD void project_gaussian_backward(const T p[gmf::kGaussianParamCount], const ViewParams<T>& view,
                                          const ProjectionCache<T>& cache, const Splat2DGrad<T>& g,
                                          T out[gmf::kGaussianParamCount]) {
  gmf::GaussianFrame<T> f;
  gmf::prepare_gaussian(p, f);
  out[gmf::kLogit] += gmf::sigmoid_vjp(f.a, g.amplitude);

  // Conic -> Σ2D. P = [[pa, pb], [pb, pc]]; Ĝ = [[ga, gb/2], [gb/2, gc]].
  const T a = cache.cov2d[0], b = cache.cov2d[1], c = cache.cov2d[2];
  const T inv_det = T(1) / (a * c - b * b);
  const T pa = c * inv_det, pb = -b * inv_det, pc = a * inv_det;
  const T ga = g.con_a, gb = T(0.5) * g.con_b, gc = g.con_c;
  // P Ĝ P (symmetric); dL/dΣ2D = −P Ĝ P.
  const T t00 = pa * ga + pb * gb, t01 = pa * gb + pb * gc;
  const T t10 = pb * ga + pc * gb, t11 = pb * gb + pc * gc;
  const T S00 = -(t00 * pa + t01 * pb);
  const T S01 = -(t00 * pb + t01 * pc);
  const T S11 = -(t10 * pb + t11 * pc);
  // G_S as a full symmetric matrix [[S00, S01], [S01, S11]] (low_pass has no parameters).

  const T* mc = cache.mean_cam;
  const T iz = T(1) / mc[2];
  T W[6], j[4];
  projection_jacobian(view, mc, W, j);
  T cov[9];
  gmf::world_covariance(f, cov);
  // dL/dΣ = Wᵀ G_S W (3x3 symmetric)
  T GW[6];  // G_S W (2x3)
  for (int k = 0; k < 3; ++k) {
    GW[k] = S00 * W[k] + S01 * W[3 + k];
    GW[3 + k] = S01 * W[k] + S11 * W[3 + k];
  }
  T dcov[9];
  for (int r = 0; r < 3; ++r) {
    for (int k = 0; k < 3; ++k) dcov[3 * r + k] = W[r] * GW[k] + W[3 + r] * GW[3 + k];
  }
  // dL/dW = 2 G_S W Σ (2x3)
  T dW[6];
  for (int r = 0; r < 2; ++r) {
    for (int k = 0; k < 3; ++k) {
      dW[3 * r + k] = T(2) * (GW[3 * r] * cov[k] + GW[3 * r + 1] * cov[3 + k] + GW[3 * r + 2] * cov[6 + k]);
    }
  }
  // W row 0 = j00 R0 + j02 R2, row 1 = j11 R1 + j12 R2  ->  dL/dJ entries.
  T dj00 = 0, dj02 = 0, dj11 = 0, dj12 = 0;
  for (int k = 0; k < 3; ++k) {
    dj00 += dW[k] * view.R[k];
    dj02 += dW[k] * view.R[6 + k];
    dj11 += dW[3 + k] * view.R[3 + k];
    dj12 += dW[3 + k] * view.R[6 + k];
  }
  // μ_cam from μ2D (Eq. 5) and from J (Eq. 4).
  T dmc[3];
  dmc[0] = g.u * view.fx * iz + dj02 * (-view.fx * iz * iz);
  dmc[1] = g.v * view.fy * iz + dj12 * (-view.fy * iz * iz);
  dmc[2] = g.u * (-view.fx * mc[0] * iz * iz) + g.v * (-view.fy * mc[1] * iz * iz) + dj00 * (-view.fx * iz * iz) +
           dj11 * (-view.fy * iz * iz) + dj02 * (T(2) * view.fx * mc[0] * iz * iz * iz) +
           dj12 * (T(2) * view.fy * mc[1] * iz * iz * iz);
  // μ_cam = R μ + t
  for (int k = 0; k < 3; ++k) {
    out[gmf::kMeanX + k] += view.R[k] * dmc[0] + view.R[3 + k] * dmc[1] + view.R[6 + k] * dmc[2];
  }

  // Σ = M Mᵀ, M = R(q̂) diag(s) (dL/dΣ is symmetric), then s = exp(log s) and q̂ = q / |q|.
  T dR[9], ds[3], dq[4];
  gmf::covariance_from_axes_vjp(f.R, f.scale, dcov, dR, ds);
  for (int k = 0; k < 3; ++k) out[gmf::kLogScale0 + k] += ds[k] * f.scale[k];
  gmf::rotation_vjp(f, dR, dq);
  for (int k = 0; k < 4; ++k) out[gmf::kRotW + k] += dq[k];
}

}  // namespace hisnegs::splat
