// SPDX-License-Identifier: Apache-2.0
// The TBB back end of SplatRenderer: per-Gaussian projection in parallel, an
// amplitude-ordered counting sort into 16x16 tiles (no depth sort: soft-MIP is
// order independent), tiles rasterized in parallel by detail/splat_cpu_tiles,
// and a deterministic backward (per-entry sums combined in entry order).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <stdexcept>
#include <utility>
#include <vector>

#include "io/error.hpp"
#include "splat/detail/splat_cpu_tiles.hpp"
#include "splat/splat_renderer.hpp"

namespace hisnegs::splat {
namespace {

using detail::kAmplitudeBuckets;
using gmf::kGaussianParamCount;

class CpuSplatRenderer final : public SplatRenderer {
 public:
  void forward(std::span<const float> params, const Intrinsics& K, const CameraView& view,
               const SplatSettings& settings, std::span<float> image) override;
  void backward(std::span<const float> dL_dimage, std::span<float> dL_dparams, std::span<float> screen_grad) override;
  void soft_state(std::span<float> m, std::span<float> S) const override {
    if (!settings_.soft() || m.size() != m_.size() || S.size() != S_.size()) {
      throw std::logic_error("splat: soft_state needs a soft-MIP forward of the spans' size");
    }
    std::copy(m_.begin(), m_.end(), m.begin());
    std::copy(S_.begin(), S_.end(), S.begin());
  }
  [[nodiscard]] const SplatFrameStats& stats() const override { return stats_; }
  [[nodiscard]] Backend backend() const override { return Backend::kCpu; }

 private:
  void bin(std::size_t K);
  // The tiles a Gaussian's δ ellipse reaches: its bounding box's tile rectangle
  // [x0, x1] × [ty0, ty1] and, when it has at most kStoredBands tile rows, the
  // columns [tx0[i], tx1[i]] of row ty0 + i that the ellipse itself reaches
  // (elongated ellipses leave many box tiles untouched; tx1 < tx0: none).
  static constexpr int kStoredBands = detail::kBandsAtOnce;
  struct GaussianTiles {
    std::int16_t ty0, ty1, x0, x1;
    std::int16_t tx0[kStoredBands], tx1[kStoredBands];
  };
  bool find_tiles(std::size_t k, const Splat2D<float>& s);
  bool band_job(std::size_t k, detail::BandJob* job);
  // Calls fn(ty, tx0, tx1) for every tile row ty of `t` (Gaussian k) with the run
  // of tile columns [tx0, tx1] the ellipse reaches there (tx1 < tx0: none).
  template <class Fn>
  void for_each_run(const GaussianTiles& t, std::size_t k, Fn&& fn) const {
    if (t.ty1 - t.ty0 < kStoredBands) {
      for (int ty = t.ty0; ty <= t.ty1; ++ty) fn(ty, t.tx0[ty - t.ty0], t.tx1[ty - t.ty0]);
      return;
    }
    for_each_tile_run(rows_[k], TileRect{t.x0, t.ty0, t.x1, t.ty1}, fn);
  }
  [[nodiscard]] detail::TileFrame tile_frame(int tile) const;
  // backward's steps: the 2D gradient sums per Gaussian (gaussian_grads_) of a hard
  // or a soft forward, then through the projection to the 11 parameters.
  void hard_grads(std::span<const float> dL_dimage);
  void soft_grads(std::span<const float> dL_dimage);
  void project_grads(std::span<float> dL_dparams, std::span<float> screen_grad) const;
  [[nodiscard]] detail::TileGaussians tile_gaussians(int tile) const;

  // The last forward (all reused between frames: no allocation once sizes settle).
  std::vector<float> params_;
  Intrinsics intrinsics_;
  CameraView view_;
  SplatSettings settings_;
  ViewParams<float> view_params_{};
  int tiles_x_ = 0, tiles_y_ = 0;
  std::vector<Splat2D<float>> splats_;
  std::vector<std::int16_t> bucket_;          // per Gaussian: amplitude bucket (descending), −1 when not visible
  std::vector<GaussianTiles> tiles_;          // per Gaussian
  std::vector<GaussianTiles> ordered_tiles_;  // per visible Gaussian, in order_
  std::vector<EllipseRows<float>> rows_;      // per Gaussian: its ellipse row by row, for binning
  std::vector<std::uint32_t> order_;          // visible Gaussians, amplitude descending
  std::vector<std::uint32_t> bucket_count_;
  std::vector<std::uint32_t> tile_offset_;   // tiles + 1
  std::vector<std::uint32_t> chunk_cursor_;  // per (chunk of order_, tile): entry count, then write cursor
  std::vector<std::int32_t> chunk_diff_;     // per (chunk, tile row, tile column + 1): count differences
  std::vector<std::uint32_t> entries_;       // Gaussian id per (tile, rank)
  std::vector<detail::PackedSplat> packed_;  // per Gaussian: its 2D parameters for the tile kernels
  std::vector<float> m_, S_, I_;             // per pixel
  std::vector<std::int32_t> argmax_;         // per pixel, hard mode with keep_argmax: the largest term's Gaussian
  std::vector<std::uint8_t> floor_above_;    // per pixel, soft mode with a floor: the floor won the max
  std::vector<float> masked_dL_;             // backward scratch: dL/dI with floor_above_ pixels zeroed
  std::vector<float> entry_grads_;           // 6 per entry
  std::vector<double> gaussian_grads_;       // 6 per Gaussian
  SplatFrameStats stats_;
};

// The rasterizer's copy of a projected Gaussian (its inverse terms precomputed).
detail::PackedSplat pack_splat(const Splat2D<float>& s) {
  detail::PackedSplat p;
  p.u = s.u;
  p.v = s.v;
  p.A = s.con_a;
  p.B = s.con_b;
  p.C = s.con_c;
  p.amp = s.amplitude;
  p.ln_amp = std::log(std::max(s.amplitude, 1e-30f));  // finite
  p.inv_A = s.visible ? 1.0f / s.con_a : 0.0f;
  p.inv_C = s.visible ? 1.0f / s.con_c : 0.0f;
  p.det = s.con_a * s.con_c - s.con_b * s.con_b;
  return p;
}

// forward()'s argument checks; returns the pixel count.
std::size_t check_forward_arguments(std::span<const float> params, const Intrinsics& K,
                                    const SplatSettings& settings, std::span<float> image) {
  if (params.size() % kGaussianParamCount != 0) {
    throw std::invalid_argument("splat: parameter array of " + std::to_string(params.size()) +
                                " floats is not a whole number of Gaussians");
  }
  const std::size_t pixels = static_cast<std::size_t>(K.width) * K.height;
  if (image.size() != pixels) throw std::invalid_argument("splat: image span does not match the intrinsics");
  if (!settings.floor.empty() && settings.floor.size() != pixels) {
    throw std::invalid_argument("splat: floor span does not match the intrinsics");
  }
  return pixels;
}

void CpuSplatRenderer::forward(std::span<const float> params, const Intrinsics& K, const CameraView& view,
                               const SplatSettings& settings, std::span<float> image) {
  const std::size_t pixels = check_forward_arguments(params, K, settings, image);
  params_.assign(params.begin(), params.end());
  intrinsics_ = K;
  view_ = view;
  settings_ = settings;
  view_params_ = make_splat_view<float>(K, view);
  const std::size_t count = params.size() / kGaussianParamCount;
  tiles_x_ = (K.width + kTileSize - 1) / kTileSize;
  tiles_y_ = (K.height + kTileSize - 1) / kTileSize;

  // 1. Project every Gaussian (Eq. 2-6) and find its tile rectangle.
  splats_.resize(count);
  packed_.resize(count);
  tiles_.resize(count);
  rows_.resize(count);
  bucket_.resize(count);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 1024), [&](const auto& range) {
    std::array<detail::BandJob, 256> jobs;  // tile_bands in batches
    std::size_t pending = 0;
    for (std::size_t k = range.begin(); k != range.end(); ++k) {
      Splat2D<float> s =
          project_gaussian(&params_[kGaussianParamCount * k], view_params_, settings.cutoff, settings.low_pass);
      if (s.visible) s.visible = find_tiles(k, s);
      if (s.visible && band_job(k, &jobs[pending]) && ++pending == jobs.size()) {
        detail::tile_bands(jobs.data(), pending);
        pending = 0;
      }
      bucket_[k] = s.visible ? static_cast<std::int16_t>(kAmplitudeBuckets - 1 -
                                                         std::clamp(static_cast<int>(s.amplitude * kAmplitudeBuckets),
                                                                    0, kAmplitudeBuckets - 1))
                             : std::int16_t{-1};
      splats_[k] = s;
      packed_[k] = pack_splat(s);
    }
    detail::tile_bands(jobs.data(), pending);
  });
  bin(count);

  // 2. Rasterize the tiles.
  m_.resize(pixels);
  S_.resize(pixels);
  I_.resize(pixels);
  const bool keep_argmax = !settings.soft() && settings.keep_argmax;
  argmax_.resize(keep_argmax ? pixels : 0);
  const int tiles = tiles_x_ * tiles_y_;
  std::vector<std::int64_t> skipped(static_cast<std::size_t>(tiles), 0);
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles, 1), [&](const auto& range) {
    for (int t = range.begin(); t != range.end(); ++t) {
      detail::forward_tile(tile_frame(t), tile_gaussians(t), m_.data(), S_.data(), I_.data(),
                           keep_argmax ? argmax_.data() : nullptr, &skipped[t]);
    }
  });
  stats_.skipped_terms = 0;
  for (std::int64_t s : skipped) stats_.skipped_terms += s;
  std::copy(I_.begin(), I_.end(), image.begin());
  floor_above_.clear();
  if (settings.soft() && !settings.floor.empty()) {  // max(soft MIP, floor); no gradient where the floor wins
    floor_above_.resize(pixels);
    for (std::size_t i = 0; i < pixels; ++i) {
      floor_above_[i] = settings.floor[i] > I_[i] ? 1 : 0;
      if (floor_above_[i]) image[i] = settings.floor[i];
    }
  }
  settings_.floor = {};  // the caller's buffer; the backward reads only the state it left
}

// Gaussian k's tiles (GaussianTiles); false when its bounding box misses the image
// or is not finite.
bool CpuSplatRenderer::find_tiles(std::size_t k, const Splat2D<float>& s) {
  TileRect r;
  if (!splat_tile_rect(s, intrinsics_.width, intrinsics_.height, &r)) return false;
  GaussianTiles& t = tiles_[k];
  t.x0 = static_cast<std::int16_t>(r.x0);
  t.x1 = static_cast<std::int16_t>(r.x1);
  t.ty0 = static_cast<std::int16_t>(r.y0);
  t.ty1 = static_cast<std::int16_t>(r.y1);
  rows_[k] = ellipse_rows(s, settings_.cutoff, kBinWiden);
  return true;
}

// The tile_bands job of Gaussian k, false when it has more tile rows than are kept.
bool CpuSplatRenderer::band_job(std::size_t k, detail::BandJob* job) {
  GaussianTiles& t = tiles_[k];
  const int rows = t.ty1 - t.ty0 + 1;
  if (rows > kStoredBands) return false;
  const EllipseRows<float>& e = rows_[k];
  *job = {{e.u, e.v, e.slope, e.k1, e.k2, e.x_right, e.dy_right, kBinPad}, t.ty0, rows, t.x0, t.x1, t.tx0, t.tx1};
  return true;
}

// Counting sorts: visible Gaussians by amplitude (descending, ties by index) into
// order_, then (tile, order) pairs into entries_.
void CpuSplatRenderer::bin(std::size_t K) {
  bucket_count_.assign(kAmplitudeBuckets + 1, 0);
  int visible = 0;
  for (std::size_t k = 0; k < K; ++k) {
    if (bucket_[k] < 0) continue;
    ++bucket_count_[bucket_[k] + 1];
    ++visible;
  }
  for (int b = 0; b < kAmplitudeBuckets; ++b) bucket_count_[b + 1] += bucket_count_[b];
  // The tile lists are copied into amplitude order too, so that both passes below
  // read them sequentially (reading them through order_ cost a cache miss each).
  order_.resize(static_cast<std::size_t>(visible));
  ordered_tiles_.resize(static_cast<std::size_t>(visible));
  for (std::size_t k = 0; k < K; ++k) {
    if (bucket_[k] < 0) continue;
    const std::uint32_t at = bucket_count_[bucket_[k]]++;
    order_[at] = static_cast<std::uint32_t>(k);
    ordered_tiles_[at] = tiles_[k];
  }
  stats_.visible = visible;

  // (tile, order) pairs: order_ is cut into chunks that count their entries per tile
  // and then scatter them in parallel; offsets run tile-major, chunk-minor, so
  // entries_ is exactly what one serial pass would write (deterministic).
  const int tiles = tiles_x_ * tiles_y_;
  const int chunks = std::clamp(visible / 4096, 1, 32);
  chunk_cursor_.resize(static_cast<std::size_t>(chunks) * tiles);  // written by the count pass
  auto chunk_range = [&](int c) {
    return std::pair<std::size_t, std::size_t>(static_cast<std::size_t>(visible) * c / chunks,
                                               static_cast<std::size_t>(visible) * (c + 1) / chunks);
  };
  // Counted as differences along each tile row (+1 at a run's first tile, −1 past
  // its last), then summed: two updates per row run instead of one per tile, and
  // no branch per tile.
  const int stride = tiles_x_ + 1;
  chunk_diff_.assign(static_cast<std::size_t>(chunks) * tiles_y_ * stride, 0);
  tbb::parallel_for(0, chunks, [&](int c) {
    std::int32_t* diff = chunk_diff_.data() + static_cast<std::size_t>(c) * tiles_y_ * stride;
    const auto [lo, hi] = chunk_range(c);
    for (std::size_t i = lo; i < hi; ++i) {
      for_each_run(ordered_tiles_[i], order_[i], [&](int ty, int tx0, int tx1) {
        if (tx0 > tx1) return;
        ++diff[ty * stride + tx0];
        --diff[ty * stride + tx1 + 1];
      });
    }
    std::uint32_t* count = chunk_cursor_.data() + static_cast<std::size_t>(c) * tiles;
    for (int ty = 0; ty < tiles_y_; ++ty) {
      std::int32_t running = 0;
      for (int tx = 0; tx < tiles_x_; ++tx) {
        running += diff[ty * stride + tx];
        count[ty * tiles_x_ + tx] = static_cast<std::uint32_t>(running);
      }
    }
  });
  tile_offset_.resize(static_cast<std::size_t>(tiles) + 1);
  std::uint32_t running = 0;
  for (int t = 0; t < tiles; ++t) {
    tile_offset_[t] = running;
    for (int c = 0; c < chunks; ++c) {
      std::uint32_t& slot = chunk_cursor_[static_cast<std::size_t>(c) * tiles + t];
      const std::uint32_t n = slot;
      slot = running;
      running += n;
    }
  }
  tile_offset_[tiles] = running;
  entries_.resize(running);
  stats_.tile_entries = static_cast<std::int64_t>(entries_.size());
  tbb::parallel_for(0, chunks, [&](int c) {
    std::uint32_t* cursor = chunk_cursor_.data() + static_cast<std::size_t>(c) * tiles;
    const auto [lo, hi] = chunk_range(c);
    for (std::size_t i = lo; i < hi; ++i) {
      const std::uint32_t k = order_[i];
      for_each_run(ordered_tiles_[i], k, [&](int ty, int tx0, int tx1) {
        for (int tx = tx0; tx <= tx1; ++tx) entries_[cursor[ty * tiles_x_ + tx]++] = k;
      });
    }
  });
}

detail::TileFrame CpuSplatRenderer::tile_frame(int tile) const {
  detail::TileFrame f{};
  f.x0 = (tile % tiles_x_) * kTileSize;
  f.y0 = (tile / tiles_x_) * kTileSize;
  f.width = std::min(kTileSize, intrinsics_.width - f.x0);
  f.height = std::min(kTileSize, intrinsics_.height - f.y0);
  f.stride = intrinsics_.width;
  f.k = settings_;
  f.k.count_skipped = f.k.soft() && settings_.count_skipped;
  f.floor = settings_.floor.empty() ? nullptr : settings_.floor.data();  // forward only
  return f;
}

// The tile's entries (Gaussian ids) into the packed 2D parameters.
detail::TileGaussians CpuSplatRenderer::tile_gaussians(int tile) const {
  const std::uint32_t lo = tile_offset_[tile], n = tile_offset_[tile + 1] - lo;
  return {packed_.data(), entries_.data() + lo, static_cast<int>(n)};
}

void CpuSplatRenderer::backward(std::span<const float> dL_dimage, std::span<float> dL_dparams,
                                std::span<float> screen_grad) {
  if (!settings_.soft() && argmax_.empty()) {
    throw std::logic_error("splat: backward needs a soft-MIP forward, or a hard one with keep_argmax");
  }
  if (dL_dimage.size() != I_.size() || dL_dparams.size() != params_.size() ||
      (!screen_grad.empty() && screen_grad.size() != splats_.size())) {
    throw std::invalid_argument("splat: backward spans do not match the last forward");
  }
  if (!settings_.soft()) {
    hard_grads(dL_dimage);
  } else {
    soft_grads(dL_dimage);
  }
  project_grads(dL_dparams, screen_grad);
}

// The hard MIP's subgradient: each pixel's dL/dI goes to its argmax Gaussian alone
// (none where the floor or nothing won), summed per Gaussian in pixel order.
void CpuSplatRenderer::hard_grads(std::span<const float> dL_dimage) {
  gaussian_grads_.assign(6 * splats_.size(), 0.0);
  const int width = intrinsics_.width;
  for (std::size_t i = 0; i < argmax_.size(); ++i) {
    const std::int32_t k = argmax_[i];
    if (k < 0 || dL_dimage[i] == 0.0f) continue;
    const Splat2D<float>& s = splats_[static_cast<std::size_t>(k)];
    const Splat2D<double> sd{s.u, s.v, s.con_a, s.con_b, s.con_c, s.amplitude, 0, 0, 0, true};
    Splat2DGrad<double> g;
    const int r = static_cast<int>(i / width), c = static_cast<int>(i % width);
    accumulate_pixel_grad(sd, c + 0.5, r + 0.5, static_cast<double>(dL_dimage[i]), g);
    double* out = &gaussian_grads_[6 * static_cast<std::size_t>(k)];
    out[0] += g.u, out[1] += g.v, out[2] += g.con_a, out[3] += g.con_b, out[4] += g.con_c, out[5] += g.amplitude;
  }
}

// The soft-MIP gradient: per (tile, Gaussian) sums of the 2D gradients, then per Gaussian.
void CpuSplatRenderer::soft_grads(std::span<const float> dL_dimage) {
  // Pixels where the floor was above the soft MIP pass no gradient on.
  if (!floor_above_.empty()) {
    masked_dL_.assign(dL_dimage.begin(), dL_dimage.end());
    for (std::size_t i = 0; i < masked_dL_.size(); ++i) {
      if (floor_above_[i]) masked_dL_[i] = 0.0f;
    }
    dL_dimage = masked_dL_;
  }

  // 1. Per (tile, Gaussian) sums of the 2D gradients.
  entry_grads_.resize(6 * entries_.size());
  const int tiles = tiles_x_ * tiles_y_;
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles, 1), [&](const auto& range) {
    for (int t = range.begin(); t != range.end(); ++t) {
      detail::backward_tile(tile_frame(t), tile_gaussians(t), m_.data(), S_.data(), I_.data(), dL_dimage.data(),
                            entry_grads_.data() + 6 * static_cast<std::size_t>(tile_offset_[t]));
    }
  });
  // 2. Combined per Gaussian in entry order (deterministic), in double, on one
  // thread: splitting by Gaussian id ranges over threads measured slower
  // (docs/benchmarks.md).
  gaussian_grads_.assign(6 * splats_.size(), 0.0);
  for (std::size_t e = 0; e < entries_.size(); ++e) {
    double* g = &gaussian_grads_[6 * static_cast<std::size_t>(entries_[e])];
    for (int i = 0; i < 6; ++i) g[i] += entry_grads_[6 * e + i];
  }
}

void CpuSplatRenderer::project_grads(std::span<float> dL_dparams, std::span<float> screen_grad) const {
  const std::size_t K = splats_.size();
  const ViewParams<double> view = make_splat_view<double>(intrinsics_, view_);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, K, 512), [&](const auto& range) {
    for (std::size_t k = range.begin(); k != range.end(); ++k) {
      const double* g6 = &gaussian_grads_[6 * k];
      // Invisible, or no gradient reached it (every term skipped): it would add 0.
      if (!splats_[k].visible || std::all_of(g6, g6 + 6, [](double x) { return x == 0.0; })) continue;
      double p[kGaussianParamCount];
      for (int i = 0; i < kGaussianParamCount; ++i) p[i] = params_[kGaussianParamCount * k + i];
      ProjectionCache<double> cache;
      const Splat2D<double> s = project_gaussian(p, view, double(settings_.cutoff), double(settings_.low_pass), &cache);
      if (!s.visible) continue;
      Splat2DGrad<double> g{g6[0], g6[1], g6[2], g6[3], g6[4], g6[5]};
      double out[kGaussianParamCount] = {};
      project_gaussian_backward(p, view, cache, g, out);
      for (int i = 0; i < kGaussianParamCount; ++i)
        dL_dparams[kGaussianParamCount * k + i] += static_cast<float>(out[i]);
      if (!screen_grad.empty()) screen_grad[k] += static_cast<float>(std::hypot(g6[0], g6[1]));
    }
  });
}

}  // namespace

std::unique_ptr<SplatRenderer> make_cpu_splat_renderer() { return std::make_unique<CpuSplatRenderer>(); }

}  // namespace hisnegs::splat
