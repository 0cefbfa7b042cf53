// SPDX-License-Identifier: Apache-2.0
// The training losses of report §6 (Eq. 11-15) with their exact gradients: one
// template per loss over the pixel type (float, double), TBB over fixed blocks.
#include "splat/losses.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>
#include <stdexcept>
#include <string>
#include <type_traits>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "gmf/core/gaussian_math.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::splat {

std::span<double> LossWorkspace::doubles(std::size_t count) {
  if (storage_.size() < count) storage_.resize(count);
  return {storage_.data(), count};
}

namespace {

// Throws unless render, target (and grad, when not empty) hold width*height values
// and both sides are at least `min_side`.
void check_images(const char* loss, std::size_t render, std::size_t target, std::size_t grad, int width, int height,
                  int min_side, double weight) {
  if (width < min_side || height < min_side)
    throw std::invalid_argument(std::string(loss) + ": image " + std::to_string(width) + "x" + std::to_string(height) +
                                ", each side must be >= " + std::to_string(min_side));
  const auto n = static_cast<std::size_t>(width) * static_cast<std::size_t>(height);
  if (render != n || target != n || (grad != 0 && grad != n))
    throw std::invalid_argument(std::string(loss) + ": render/target/grad hold " + std::to_string(render) + "/" +
                                std::to_string(target) + "/" + std::to_string(grad) + " values, expected " +
                                std::to_string(n) + " (grad may be empty)");
  if (!std::isfinite(weight))
    throw std::invalid_argument(std::string(loss) + ": weight " + std::to_string(weight) + " is not finite");
}

// Parallel loops over fixed blocks. TBB's own ranges split by load, so a reduction
// over them would round differently from run to run; fixed blocks, each with its own
// partial sum added up in block order, give the same bits whatever the thread count.
constexpr std::size_t kRowsPerBlock = 8;       // image rows per task
constexpr std::size_t kPixelsPerBlock = 4096;  // pixels per task (the histogram)

std::size_t block_count(std::size_t n, std::size_t block) { return (n + block - 1) / block; }

// body(block, begin, end) for the blocks [b·block, min((b+1)·block, n)) of [0, n).
template <class Body>
void for_blocks(std::size_t n, std::size_t block, const Body& body) {
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, block_count(n, block), 1), [&](const auto& range) {
    for (std::size_t b = range.begin(); b != range.end(); ++b) body(b, b * block, std::min(n, (b + 1) * block));
  });
}

template <class Body>
void for_row_blocks(std::size_t rows, const Body& body) {
  for_blocks(rows, kRowsPerBlock, body);
}

double ordered_sum(const double* values, std::size_t count) {
  double sum = 0;
  for (std::size_t i = 0; i < count; ++i) sum += values[i];
  return sum;
}

// ---------------------------------------------------------------- Eq. 11

template <class T>
double weighted_mse_impl(std::span<const T> p, std::span<const T> g, int width, int height, double w_fg, double weight,
                         std::span<T> grad) {
  check_images("weighted_mse", p.size(), g.size(), grad.size(), width, height, 1, weight);
  const std::size_t n = p.size();
  const double inv_n = 1.0 / static_cast<double>(n);
  double sum = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double w = 1.0 + (w_fg - 1.0) * g[i];
    const double d = double(p[i]) - double(g[i]);
    sum += w * d * d;
    if (!grad.empty()) grad[i] += static_cast<T>(weight * 2.0 * w * d * inv_n);
  }
  return sum * inv_n;
}

// ---------------------------------------------------------------- Eq. 12

// scipy.ndimage's Gaussian (what skimage.filters.gaussian calls): σ = 1.5, radius
// int(3.5 σ + 0.5) = 5, taps exp(-x²/(2σ²)) normalised to sum 1.
constexpr int kSsimRadius = 5;
constexpr int kSsimTaps = 2 * kSsimRadius + 1;
constexpr double kSsimC1 = 0.01 * 0.01;  // (K1 × data range)²
constexpr double kSsimC2 = 0.03 * 0.03;  // (K2 × data range)²

const std::array<double, kSsimTaps>& ssim_taps() {
  static const std::array<double, kSsimTaps> taps = [] {
    std::array<double, kSsimTaps> t{};
    double sum = 0;
    for (int k = 0; k < kSsimTaps; ++k) {
      const double x = k - kSsimRadius;
      t[k] = std::exp(-0.5 * x * x / (1.5 * 1.5));
      sum += t[k];
    }
    for (double& v : t) v /= sum;
    return t;
  }();
  return taps;
}

// Derivation of the backward. With the window w, every statistic at a valid pixel p
// is a filtered image: μx = w⋆x, μy = w⋆y, Exx = w⋆x², Eyy = w⋆y², Exy = w⋆(xy);
// σx² = Exx − μx², σy² = Eyy − μy², σxy = Exy − μx μy and
//   S = A1 A2 / (B1 B2),  A1 = 2 μx μy + C1,  A2 = 2 σxy + C2,
//                         B1 = μx² + μy² + C1, B2 = σx² + σy² + C2.
// Holding (μx, Exx, Exy) as the independent variables:
//   ∂S/∂μx  = 2 μy (A2 − A1) / (B1 B2) − 2 μx S (B2 − B1) / (B1 B2)
//   ∂S/∂Exx = −S / B2,   ∂S/∂Exy = 2 A1 / (B1 B2),
// and ∂μx(p)/∂x_q = w(p − q), ∂Exx(p)/∂x_q = 2 x_q w(p − q), ∂Exy(p)/∂x_q = y_q w(p − q). So
//   ∂mean S/∂x_q = (1/M) [(wᵀ⋆a)_q + 2 x_q (wᵀ⋆b)_q + y_q (wᵀ⋆c)_q]
// with a, b, c the three partial maps over the M valid pixels and wᵀ⋆ the adjoint of
// the valid-region filter: the same separable window, gathered back over the full image.
// The SSIM workspace of one image pair: 5 row-filtered maps (H × Wv), 3 partial
// maps (Hv × Wv), 5 rows of scratch (W) per row block, one partial sum per row block.
struct SsimBuffers {
  std::size_t W, H, Wv, Hv, M, blocks;
  double* hmap[5];
  double* part[3];
  double* scratch;
  double* block_sums;

  SsimBuffers(int width, int height, LossWorkspace& workspace)
      : W(static_cast<std::size_t>(width)),
        H(static_cast<std::size_t>(height)),
        Wv(W - 2 * kSsimRadius),
        Hv(H - 2 * kSsimRadius),
        M(Wv * Hv),
        blocks(block_count(H, kRowsPerBlock)) {
    const std::span<double> ws = workspace.doubles(5 * H * Wv + 3 * M + blocks * (5 * W + 1));
    double* at = ws.data();
    for (auto& h : hmap) h = at, at += H * Wv;
    for (auto& q : part) q = at, at += M;
    scratch = at;
    block_sums = scratch + blocks * 5 * W;
  }
};

// Row pass over x, y, x², y², xy, valid columns only, into hmap.
template <class T>
void ssim_row_pass(std::span<const T> xs, std::span<const T> ys, SsimBuffers& b) {
  const auto& w = ssim_taps();
  for_row_blocks(b.H, [&](std::size_t block, std::size_t r0, std::size_t r1) {
    double* rows[5];
    for (int ch = 0; ch < 5; ++ch) rows[ch] = b.scratch + block * 5 * b.W + ch * b.W;
    for (std::size_t r = r0; r < r1; ++r) {
      const T* xr = xs.data() + r * b.W;
      const T* yr = ys.data() + r * b.W;
      for (std::size_t c = 0; c < b.W; ++c) {
        const double x = xr[c], y = yr[c];
        rows[0][c] = x;
        rows[1][c] = y;
        rows[2][c] = x * x;
        rows[3][c] = y * y;
        rows[4][c] = x * y;
      }
      for (int ch = 0; ch < 5; ++ch) {
        const double* in = rows[ch];
        double* out = b.hmap[ch] + r * b.Wv;
        for (std::size_t c = 0; c < b.Wv; ++c) {
          double acc = 0;
          for (int k = 0; k < kSsimTaps; ++k) acc += w[k] * in[c + k];
          out[c] = acc;
        }
      }
    }
  });
}

// Column pass over the valid rows, the SSIM map, and (want_grad) its three partial
// maps scaled by `scale`. Returns mean S over the M valid pixels.
double ssim_map(SsimBuffers& b, bool want_grad, double scale) {
  const auto& w = ssim_taps();
  for_row_blocks(b.Hv, [&](std::size_t block, std::size_t r0, std::size_t r1) {
    double* stat[5];
    for (int ch = 0; ch < 5; ++ch) stat[ch] = b.scratch + block * 5 * b.W + ch * b.Wv;
    double sum = 0;
    for (std::size_t r = r0; r < r1; ++r) {
      for (int ch = 0; ch < 5; ++ch) {
        double* out = stat[ch];
        std::fill(out, out + b.Wv, 0.0);
        for (int k = 0; k < kSsimTaps; ++k) {
          const double* in = b.hmap[ch] + (r + k) * b.Wv;
          const double wk = w[k];
          for (std::size_t c = 0; c < b.Wv; ++c) out[c] += wk * in[c];
        }
      }
      for (std::size_t c = 0; c < b.Wv; ++c) {
        const double mx = stat[0][c], my = stat[1][c];
        const double vx = stat[2][c] - mx * mx, vy = stat[3][c] - my * my, vxy = stat[4][c] - mx * my;
        const double A1 = 2 * mx * my + kSsimC1, A2 = 2 * vxy + kSsimC2;
        const double B1 = mx * mx + my * my + kSsimC1, B2 = vx + vy + kSsimC2;
        const double inv_D = 1.0 / (B1 * B2);
        const double S = A1 * A2 * inv_D;
        sum += S;
        if (want_grad) {
          const std::size_t i = r * b.Wv + c;
          b.part[0][i] = scale * (2 * my * (A2 - A1) * inv_D - 2 * mx * S * (B2 - B1) * inv_D);
          b.part[1][i] = scale * (-S / B2);
          b.part[2][i] = scale * (2 * A1 * inv_D);
        }
      }
    }
    b.block_sums[block] = sum;
  });
  return ordered_sum(b.block_sums, block_count(b.Hv, kRowsPerBlock)) / static_cast<double>(b.M);
}

// Adjoint of the column pass, gathered: image row j collects the valid rows j − k,
// k = 0..10, that its window reached (into the now free row-filtered maps, H × Wv).
void ssim_column_adjoint(SsimBuffers& b) {
  const auto& w = ssim_taps();
  for_row_blocks(b.H, [&](std::size_t, std::size_t j0, std::size_t j1) {
    for (std::size_t j = j0; j < j1; ++j)
      for (int m = 0; m < 3; ++m) {
        double* out = b.hmap[m] + j * b.Wv;
        std::fill(out, out + b.Wv, 0.0);
        const std::size_t k_lo = j + 1 > b.Hv ? j + 1 - b.Hv : 0, k_hi = std::min<std::size_t>(kSsimTaps - 1, j);
        for (std::size_t k = k_lo; k <= k_hi; ++k) {
          const double* in = b.part[m] + (j - k) * b.Wv;
          const double wk = w[k];
          for (std::size_t c = 0; c < b.Wv; ++c) out[c] += wk * in[c];
        }
      }
  });
}

// Adjoint of the row pass (scattered within the row), then the chain rule into x.
template <class T>
void ssim_row_adjoint(std::span<const T> xs, std::span<const T> ys, SsimBuffers& b, std::span<T> grad) {
  const auto& w = ssim_taps();
  for_row_blocks(b.H, [&](std::size_t block, std::size_t r0, std::size_t r1) {
    double* rows[3];
    for (int m = 0; m < 3; ++m) rows[m] = b.scratch + block * 5 * b.W + m * b.W;
    for (std::size_t r = r0; r < r1; ++r) {
      for (int m = 0; m < 3; ++m) {
        double* out = rows[m];
        std::fill(out, out + b.W, 0.0);
        const double* in = b.hmap[m] + r * b.Wv;
        for (int k = 0; k < kSsimTaps; ++k) {
          const double wk = w[k];
          for (std::size_t c = 0; c < b.Wv; ++c) out[c + k] += wk * in[c];
        }
      }
      const T* xr = xs.data() + r * b.W;
      const T* yr = ys.data() + r * b.W;
      T* gr = grad.data() + r * b.W;
      for (std::size_t c = 0; c < b.W; ++c)
        gr[c] += static_cast<T>(rows[0][c] + 2.0 * double(xr[c]) * rows[1][c] + double(yr[c]) * rows[2][c]);
    }
  });
}

template <class T>
double ssim_impl(std::span<const T> xs, std::span<const T> ys, int width, int height, double weight, std::span<T> grad,
                 LossWorkspace& workspace) {
  check_images("ssim_loss", xs.size(), ys.size(), grad.size(), width, height, kSsimTaps, weight);
  SsimBuffers b(width, height, workspace);
  ssim_row_pass(xs, ys, b);
  const bool want_grad = !grad.empty();
  const double scale = -weight / static_cast<double>(b.M);  // ∂(1 − mean S)/∂S_p × weight
  const double loss = 1.0 - ssim_map(b, want_grad, scale);
  if (!want_grad) return loss;
  ssim_column_adjoint(b);
  ssim_row_adjoint(xs, ys, b, grad);
  return loss;
}

// ---------------------------------------------------------------- Eq. 13

// The edge-loss workspace: d = P − G (later ∂L/∂d), s = d smoothed down the
// columns (later ∂L/∂s), t = d smoothed along the rows (later ∂L/∂t), gx = S_x * d,
// gy = S_y * d, and one partial sum per row block. Replicated borders.
struct EdgeBuffers {
  std::size_t W, H, N, blocks;
  double *d, *s, *t, *gx, *gy, *block_sums;

  EdgeBuffers(int width, int height, LossWorkspace& workspace)
      : W(static_cast<std::size_t>(width)),
        H(static_cast<std::size_t>(height)),
        N(W * H),
        blocks(block_count(H, kRowsPerBlock)) {
    const std::span<double> ws = workspace.doubles(5 * N + blocks);
    d = ws.data();
    s = d + N;
    t = s + N;
    gx = t + N;
    gy = gx + N;
    block_sums = gy + N;
  }
  [[nodiscard]] std::size_t row_minus(std::size_t r) const { return r > 0 ? r - 1 : 0; }
  [[nodiscard]] std::size_t row_plus(std::size_t r) const { return r + 1 < H ? r + 1 : r; }
  [[nodiscard]] std::size_t col_minus(std::size_t c) const { return c > 0 ? c - 1 : 0; }
  [[nodiscard]] std::size_t col_plus(std::size_t c) const { return c + 1 < W ? c + 1 : c; }
};

// d = P − G, then its [1 2 1] smoothing down the columns (s) and along the rows (t).
template <class T>
void edge_smooth(std::span<const T> p, std::span<const T> g, EdgeBuffers& b) {
  for_row_blocks(b.H, [&](std::size_t, std::size_t r0, std::size_t r1) {
    for (std::size_t i = r0 * b.W; i < r1 * b.W; ++i) b.d[i] = double(p[i]) - double(g[i]);
  });
  for_row_blocks(b.H, [&](std::size_t, std::size_t r0, std::size_t r1) {
    for (std::size_t r = r0; r < r1; ++r) {
      const double* up = b.d + b.row_minus(r) * b.W;
      const double* mid = b.d + r * b.W;
      const double* down = b.d + b.row_plus(r) * b.W;
      double* sr = b.s + r * b.W;
      for (std::size_t c = 0; c < b.W; ++c) sr[c] = up[c] + 2.0 * mid[c] + down[c];
      double* tr = b.t + r * b.W;
      for (std::size_t c = 0; c < b.W; ++c) tr[c] = mid[b.col_minus(c)] + 2.0 * mid[c] + mid[b.col_plus(c)];
    }
  });
}

// gx, gy (the differences across the smoothing) and mean(gx² + gy²).
double edge_gradients(EdgeBuffers& b) {
  for_row_blocks(b.H, [&](std::size_t block, std::size_t r0, std::size_t r1) {
    double sum = 0;
    for (std::size_t r = r0; r < r1; ++r) {
      const double* sr = b.s + r * b.W;
      const double* t_up = b.t + b.row_minus(r) * b.W;
      const double* t_down = b.t + b.row_plus(r) * b.W;
      for (std::size_t c = 0; c < b.W; ++c) {
        const double x = sr[b.col_plus(c)] - sr[b.col_minus(c)], y = t_down[c] - t_up[c];
        b.gx[r * b.W + c] = x;
        b.gy[r * b.W + c] = y;
        sum += x * x + y * y;
      }
    }
    b.block_sums[block] = sum;
  });
  return ordered_sum(b.block_sums, b.blocks) / static_cast<double>(b.N);
}

// ∂/∂s of gx = s[cp] − s[cm] (within the row); ∂/∂t of gy = t[rp] − t[rm]: row j gets
// +gy[r] from each r with rp(r) = j and −gy[r] from each r with rm(r) = j. `a` is
// ∂(weight L)/∂gx per unit gx.
void edge_difference_adjoint(EdgeBuffers& b, double a) {
  for_row_blocks(b.H, [&](std::size_t, std::size_t j0, std::size_t j1) {
    for (std::size_t j = j0; j < j1; ++j) {
      double* sr = b.s + j * b.W;
      std::fill(sr, sr + b.W, 0.0);
      const double* gxr = b.gx + j * b.W;
      for (std::size_t c = 0; c < b.W; ++c) {
        sr[b.col_plus(c)] += a * gxr[c];
        sr[b.col_minus(c)] -= a * gxr[c];
      }
      double* tr = b.t + j * b.W;
      std::fill(tr, tr + b.W, 0.0);
      for (std::size_t r = b.row_minus(j); r <= b.row_plus(j); ++r) {
        const double coef = double(b.row_plus(r) == j) - double(b.row_minus(r) == j);
        if (coef == 0) continue;
        const double* gyr = b.gy + r * b.W;
        for (std::size_t c = 0; c < b.W; ++c) tr[c] += a * coef * gyr[c];
      }
    }
  });
}

// ∂/∂d of s = d[rm] + 2 d[r] + d[rp] (gathered over rows) and of t = d[cm] + 2 d[c] +
// d[cp] (scattered within the row), added into grad.
template <class T>
void edge_smoothing_adjoint(EdgeBuffers& b, std::span<T> grad) {
  for_row_blocks(b.H, [&](std::size_t, std::size_t j0, std::size_t j1) {
    for (std::size_t j = j0; j < j1; ++j) {
      double* dd = b.d + j * b.W;
      std::fill(dd, dd + b.W, 0.0);
      for (std::size_t r = b.row_minus(j); r <= b.row_plus(j); ++r) {
        const double coef = double(b.row_minus(r) == j) + 2.0 * double(r == j) + double(b.row_plus(r) == j);
        const double* sr = b.s + r * b.W;
        for (std::size_t c = 0; c < b.W; ++c) dd[c] += coef * sr[c];
      }
      const double* tr = b.t + j * b.W;
      for (std::size_t c = 0; c < b.W; ++c) {
        dd[b.col_minus(c)] += tr[c];
        dd[c] += 2.0 * tr[c];
        dd[b.col_plus(c)] += tr[c];
      }
      T* gr = grad.data() + j * b.W;
      for (std::size_t c = 0; c < b.W; ++c) gr[c] += static_cast<T>(dd[c]);
    }
  });
}

// Sobel S_x = [1 2 1]ᵀ ⊗ [−1 0 1] is separable: smooth down the columns, difference
// along the rows; S_y the other way round. Replicated borders: row/column i ± 1 is
// clamped to the image. The loss only sees d = P − G (Sobel is linear), so ∂L/∂P = ∂L/∂d.
// The adjoints across rows are gathered (row j collects from rows j−1..j+1 with the
// clamped coefficients) so that row blocks never write the same row.
template <class T>
double edge_impl(std::span<const T> p, std::span<const T> g, int width, int height, double weight, std::span<T> grad,
                 LossWorkspace& workspace) {
  check_images("edge_loss", p.size(), g.size(), grad.size(), width, height, 1, weight);
  EdgeBuffers b(width, height, workspace);
  edge_smooth(p, g, b);
  const double loss = edge_gradients(b);
  if (grad.empty()) return loss;
  edge_difference_adjoint(b, 2.0 * weight / static_cast<double>(b.N));  // ∂(weight L)/∂gx = a gx
  edge_smoothing_adjoint(b, grad);
  return loss;
}

// ---------------------------------------------------------------- Eq. 14

// Where one pixel's walk over the bins starts: its nearest bin b0, z0 = (c_b0 − x)/h,
// k0 = exp(−z0²/2) and the first up/down ratios of the recurrence below.
struct BinStart {
  int b0;
  double z0, k0, r_up, r_down;
};

// The bins one pixel touches. With z_b = (c_b − x)/h and δ = Δ/h, consecutive kernel
// values obey k_{b+1} = k_b r_b, r_b = exp(−z_b δ − δ²/2), r_{b+1} = r_b exp(−δ²)
// (and the mirror image downwards, whose first ratio is exp(−δ²)/r_b0), so a pixel
// costs two exp() whatever the bin count. Walking out from the nearest bin the ratios
// are <= 1 and k only decreases; the walk stops once κ = norm × k < 1e-17 ε: such a
// term moves no p_b by more than 1e-17 relative (m_b + ε >= ε), below double rounding,
// so the truncation is invisible (the brute-force test sums every bin).
struct BinWalk {
  int bins;
  double delta;   // Δ = 1 / bins
  double h;       // kernel bandwidth
  double step;    // δ = Δ / h
  double q;       // exp(−δ²)
  double norm;    // Δ / (√(2π) h): κ = norm × k
  double k_stop;  // stop walking once k < k_stop

  explicit BinWalk(const SoftHistogramOptions& o)
      : bins(o.bins),
        delta(1.0 / o.bins),
        h(o.bandwidth),
        step(delta / h),
        q(std::exp(-step * step)),
        norm(delta / (std::sqrt(2.0 * std::numbers::pi) * h)),
        k_stop(1e-17 * o.epsilon / norm) {}

  // x must be finite (the clamp keeps b0 a valid int for any finite x).
  int nearest_bin(double x) const { return static_cast<int>(std::clamp(std::floor(x * bins), 0.0, bins - 1.0)); }

  BinStart start(double x) const {
    BinStart s;
    s.b0 = nearest_bin(x);
    s.z0 = ((s.b0 + 0.5) * delta - x) / h;
    s.k0 = std::exp(-0.5 * s.z0 * s.z0);
    if (s.k0 < k_stop) {  // touches no bin; the ratios are never used
      s.r_up = s.r_down = 0;
      return s;
    }
    s.r_up = std::exp(-s.z0 * step - 0.5 * step * step);
    // exp(z0 δ − δ²/2) = q / r_up, unless a narrow kernel (δ > 27) underflowed q or r_up.
    s.r_down = q > 0 && s.r_up > 0 ? q / s.r_up : std::exp(s.z0 * step - 0.5 * step * step);
    return s;
  }

  // Calls f(b, k_b, z_b) for every bin whose kernel value k_b reaches k_stop.
  template <class F>
  void walk(const BinStart& s, F&& f) const {
    // Locals: f writes through a double*, which could alias the members otherwise.
    const double k_min = k_stop, ratio = q, dz = step;
    const int n = bins;
    if (s.k0 < k_min) return;
    f(s.b0, s.k0, s.z0);
    double k = s.k0, r = s.r_up;
    for (int b = s.b0 + 1; b < n; ++b) {
      k *= r;
      if (k < k_min) break;
      r *= ratio;
      f(b, k, s.z0 + (b - s.b0) * dz);
    }
    k = s.k0;
    r = s.r_down;
    for (int b = s.b0 - 1; b >= 0; --b) {
      k *= r;
      if (k < k_min) break;
      r *= ratio;
      f(b, k, s.z0 - (s.b0 - b) * dz);
    }
  }
};

// p_b = (m_b + ε) / Σ (m_b' + ε) into `p`; returns Z = Σ (m_b' + ε). Each block of
// pixels fills its own histogram in `partial` (block_count(N, kPixelsPerBlock) × bins),
// added up in block order. When `starts` is not null it keeps each pixel's walk start
// (z0, k0, r_up, r_down: 4 doubles) for the backward pass, which then needs no exp().
template <class T>
double soft_histogram(std::span<const T> image, const BinWalk& walk, double epsilon, double* partial, double* p,
                      double* starts) {
  const auto B = static_cast<std::size_t>(walk.bins);
  for_blocks(image.size(), kPixelsPerBlock, [&](std::size_t block, std::size_t i0, std::size_t i1) {
    double* h = partial + block * B;
    std::fill(h, h + B, 0.0);
    for (std::size_t i = i0; i < i1; ++i) {
      const double x = image[i];
      if (!std::isfinite(x))
        throw std::invalid_argument("intensity_kl_loss: pixel " + std::to_string(i) + " is " + std::to_string(x) +
                                    ", expected a finite value");
      const BinStart s = walk.start(x);
      if (starts) {
        double* st = starts + 4 * i;
        st[0] = s.z0, st[1] = s.k0, st[2] = s.r_up, st[3] = s.r_down;
      }
      walk.walk(s, [h](int b, double k, double) { h[b] += k; });
    }
  });
  const std::size_t blocks = block_count(image.size(), kPixelsPerBlock);
  std::fill(p, p + B, 0.0);
  for (std::size_t block = 0; block < blocks; ++block)
    for (std::size_t b = 0; b < B; ++b) p[b] += partial[block * B + b];
  const double mass_scale = walk.norm / static_cast<double>(image.size());
  double z = 0;
  for (std::size_t b = 0; b < B; ++b) {
    p[b] = p[b] * mass_scale + epsilon;
    z += p[b];
  }
  for (std::size_t b = 0; b < B; ++b) p[b] /= z;
  return z;
}

// L = Σ p_b log(p_b/q_b). With ∂L/∂p_b = log(p_b/q_b) + 1 and ∂p_b/∂m_c = (δ_bc − p_b)/Z,
// ∂L/∂m_c = (log(p_c/q_c) − L)/Z; ∂m_c/∂x_i = (norm/N) ∂k_c/∂x_i = (norm/N) k_c z_c / h.
template <class T>
double intensity_kl_impl(std::span<const T> render, std::span<const T> target, int width, int height,
                         const SoftHistogramOptions& o, double weight, std::span<T> grad, LossWorkspace& workspace) {
  check_images("intensity_kl_loss", render.size(), target.size(), grad.size(), width, height, 1, weight);
  o.validate();
  const BinWalk walk(o);
  const auto B = static_cast<std::size_t>(o.bins);
  const std::size_t N = render.size();
  const std::size_t blocks = block_count(N, kPixelsPerBlock);
  // 3 histograms, the per-block partial histograms, then (with a gradient) 4 doubles of
  // walk start per pixel.
  const std::span<double> ws = workspace.doubles((3 + blocks) * B + (grad.empty() ? 0 : 4 * N));
  double* p = ws.data();
  double* q = p + B;
  double* g = q + B;
  double* partial = g + B;
  double* starts = grad.empty() ? nullptr : partial + blocks * B;
  const double z = soft_histogram(render, walk, o.epsilon, partial, p, starts);
  soft_histogram(target, walk, o.epsilon, partial, q, nullptr);
  double loss = 0;
  for (std::size_t b = 0; b < B; ++b) loss += p[b] * std::log(p[b] / q[b]);
  if (grad.empty()) return loss;

  const double a = weight * walk.norm / (static_cast<double>(N) * walk.h);
  for (std::size_t b = 0; b < B; ++b) g[b] = a * (std::log(p[b] / q[b]) - loss) / z;
  for_blocks(N, kPixelsPerBlock, [&](std::size_t, std::size_t i0, std::size_t i1) {
    for (std::size_t i = i0; i < i1; ++i) {
      const double* st = starts + 4 * i;
      const BinStart s{walk.nearest_bin(render[i]), st[0], st[1], st[2], st[3]};
      double acc = 0;
      walk.walk(s, [g, &acc](int b, double k, double zb) { acc += g[b] * k * zb; });
      grad[i] += static_cast<T>(acc);
    }
  });
  return loss;
}

// ---------------------------------------------------------------- Eq. 15

template <class T>
double scale_regularizer_impl(std::span<const T> params, double s_min, double s_max, double weight, std::span<T> grad) {
  if (params.size() % gmf::kGaussianParamCount != 0 || (!grad.empty() && grad.size() != params.size()))
    throw std::invalid_argument("scale_regularizer: params/grad hold " + std::to_string(params.size()) + "/" +
                                std::to_string(grad.size()) + " values, expected whole Gaussians (grad may be empty)");
  if (!(s_min > 0 && s_max > s_min))
    throw std::invalid_argument("scale_regularizer: s_min " + std::to_string(s_min) + ", s_max " +
                                std::to_string(s_max) + ", expected 0 < s_min < s_max");
  if (!std::isfinite(weight))
    throw std::invalid_argument("scale_regularizer: weight " + std::to_string(weight) + " is not finite");
  double sum = 0;
  for (std::size_t k = 0; k < params.size(); k += gmf::kGaussianParamCount) {
    for (std::size_t a = 0; a < 3; ++a) {
      const std::size_t i = k + gmf::kLogScale0 + a;
      const double s = std::exp(double(params[i]));
      double ds = 0;  // ∂L/∂log s = s ∂L/∂s
      if (s < s_min) {
        sum += s_min - s;
        ds = -s;
      } else if (s > s_max) {
        sum += s - s_max;
        ds = s;
      }
      if (!grad.empty() && ds != 0) grad[i] += static_cast<T>(weight * ds);
    }
  }
  return sum;
}

// ---------------------------------------------------------------- Eq. 16

template <class T>
double wmse_term(std::span<const T> render, std::span<const T> target, int width, int height,
                 const ImageLossWeights& w, double weight, std::span<T> grad, LossWorkspace&) {
  return weighted_mse_impl(render, target, width, height, w.foreground_weight, weight, grad);
}
template <class T>
double ssim_term(std::span<const T> render, std::span<const T> target, int width, int height,
                 const ImageLossWeights&, double weight, std::span<T> grad, LossWorkspace& workspace) {
  return ssim_impl(render, target, width, height, weight, grad, workspace);
}
template <class T>
double edge_term(std::span<const T> render, std::span<const T> target, int width, int height,
                 const ImageLossWeights&, double weight, std::span<T> grad, LossWorkspace& workspace) {
  return edge_impl(render, target, width, height, weight, grad, workspace);
}
template <class T>
double intensity_term(std::span<const T> render, std::span<const T> target, int width, int height,
                      const ImageLossWeights& w, double weight, std::span<T> grad, LossWorkspace& workspace) {
  return intensity_kl_impl(render, target, width, height, w.histogram, weight, grad, workspace);
}

constexpr std::array<ImageLossEntry, 4> kImageLosses{{
    {"wmse", &ImageLossWeights::wmse, &ImageLossTerms::wmse, &wmse_term<float>, &wmse_term<double>},
    {"ssim", &ImageLossWeights::ssim, &ImageLossTerms::ssim, &ssim_term<float>, &ssim_term<double>},
    {"edge", &ImageLossWeights::edge, &ImageLossTerms::edge, &edge_term<float>, &edge_term<double>},
    {"intensity", &ImageLossWeights::intensity, &ImageLossTerms::intensity, &intensity_term<float>,
     &intensity_term<double>},
}};

void check_weights(const ImageLossWeights& w) {
  for (const ImageLossEntry& loss : kImageLosses) {
    const double value = w.*loss.weight;
    if (!(value >= 0 && std::isfinite(value)))
      throw std::invalid_argument(std::string("ImageLossWeights.") + loss.name + " = " + std::to_string(value) +
                                  ": must be finite and >= 0");
  }
}

template <class T>
ImageLossTerms combined_impl(std::span<const T> render, std::span<const T> target, int width, int height,
                             const ImageLossWeights& w, std::span<T> grad, LossWorkspace& workspace) {
  check_weights(w);
  constexpr double kNotEvaluated = std::numeric_limits<double>::quiet_NaN();
  ImageLossTerms terms{kNotEvaluated, kNotEvaluated, kNotEvaluated, kNotEvaluated, 0.0};
  for (const ImageLossEntry& loss : kImageLosses) {
    const double weight = w.*loss.weight;
    if (!(weight > 0)) continue;
    ImageLossFunction<T> f = nullptr;
    if constexpr (std::is_same_v<T, float>) {
      f = loss.of_float;
    } else {
      f = loss.of_double;
    }
    terms.*loss.value = f(render, target, width, height, w, weight, grad, workspace);
    terms.total += weight * terms.*loss.value;
  }
  return terms;
}

}  // namespace

void SoftHistogramOptions::validate() const {
  if (bins < 2 || bins > 4096)
    throw std::invalid_argument("SoftHistogramOptions.bins = " + std::to_string(bins) + ": must be in [2, 4096]");
  if (!(bandwidth > 0 && std::isfinite(bandwidth)))
    throw std::invalid_argument("SoftHistogramOptions.bandwidth = " + std::to_string(bandwidth) + ": must be > 0");
  if (!(epsilon > 0 && std::isfinite(epsilon)))
    throw std::invalid_argument("SoftHistogramOptions.epsilon = " + std::to_string(epsilon) + ": must be > 0");
}

ImageLossWeights image_loss_weights(const TrainOptions& train) {
  ImageLossWeights w;
  w.foreground_weight = train.foreground_weight;
  w.wmse = 1.0;
  w.ssim = train.lambda_ssim;
  w.edge = train.lambda_edge;
  w.intensity = train.lambda_intensity;
  return w;
}

double weighted_mse(std::span<const float> render, std::span<const float> target, int width, int height,
                    double foreground_weight, double weight, std::span<float> grad) {
  return weighted_mse_impl(render, target, width, height, foreground_weight, weight, grad);
}
double weighted_mse(std::span<const double> render, std::span<const double> target, int width, int height,
                    double foreground_weight, double weight, std::span<double> grad) {
  return weighted_mse_impl(render, target, width, height, foreground_weight, weight, grad);
}

double ssim_loss(std::span<const float> render, std::span<const float> target, int width, int height, double weight,
                 std::span<float> grad, LossWorkspace& workspace) {
  return ssim_impl(render, target, width, height, weight, grad, workspace);
}
double ssim_loss(std::span<const double> render, std::span<const double> target, int width, int height, double weight,
                 std::span<double> grad, LossWorkspace& workspace) {
  return ssim_impl(render, target, width, height, weight, grad, workspace);
}

double edge_loss(std::span<const float> render, std::span<const float> target, int width, int height, double weight,
                 std::span<float> grad, LossWorkspace& workspace) {
  return edge_impl(render, target, width, height, weight, grad, workspace);
}
double edge_loss(std::span<const double> render, std::span<const double> target, int width, int height, double weight,
                 std::span<double> grad, LossWorkspace& workspace) {
  return edge_impl(render, target, width, height, weight, grad, workspace);
}

double intensity_kl_loss(std::span<const float> render, std::span<const float> target, int width, int height,
                         const SoftHistogramOptions& histogram, double weight, std::span<float> grad,
                         LossWorkspace& workspace) {
  return intensity_kl_impl(render, target, width, height, histogram, weight, grad, workspace);
}
double intensity_kl_loss(std::span<const double> render, std::span<const double> target, int width, int height,
                         const SoftHistogramOptions& histogram, double weight, std::span<double> grad,
                         LossWorkspace& workspace) {
  return intensity_kl_impl(render, target, width, height, histogram, weight, grad, workspace);
}

double scale_regularizer(std::span<const float> params, double s_min, double s_max, double weight,
                         std::span<float> grad) {
  return scale_regularizer_impl(params, s_min, s_max, weight, grad);
}
double scale_regularizer(std::span<const double> params, double s_min, double s_max, double weight,
                         std::span<double> grad) {
  return scale_regularizer_impl(params, s_min, s_max, weight, grad);
}

std::span<const ImageLossEntry> image_losses() { return kImageLosses; }

ImageLossTerms combined_image_loss(std::span<const float> render, std::span<const float> target, int width, int height,
                                   const ImageLossWeights& weights, std::span<float> grad, LossWorkspace& workspace) {
  return combined_impl(render, target, width, height, weights, grad, workspace);
}
ImageLossTerms combined_image_loss(std::span<const double> render, std::span<const double> target, int width,
                                   int height, const ImageLossWeights& weights, std::span<double> grad,
                                   LossWorkspace& workspace) {
  return combined_impl(render, target, width, height, weights, grad, workspace);
}

}  // namespace hisnegs::splat
