// The TBB back end of SplatRenderer: per-Gaussian projection in parallel, an
// amplitude-ordered counting sort into 16x16 tiles (no depth sort: soft-MIP is
// order independent), tiles rasterized in parallel by detail/splat_cpu_tiles,
// and a deterministic backward (per-entry sums combined in entry order).
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
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

constexpr int kParams = gmf::kNumGaussianParams;
constexpr int kAmplitudeBuckets = 1024;
// Binning widens δ by this factor and the ellipse by kBinPad pixels each side, so
// rounding never drops a tile the kernels' per-pixel test q <= δ would reach.
constexpr float kBinWiden = 1.0f + 1e-3f;
constexpr float kBinPad = 0.25f;

class CpuSplatRenderer final : public SplatRenderer {
 public:
  void forward(std::span<const float> params, const Intrinsics& K, const CameraView& view,
               const SplatSettings& settings, std::span<float> image) override;
  void backward(std::span<const float> dL_dimage, std::span<float> dL_dparams, std::span<float> screen_grad) override;
  [[nodiscard]] const SplatFrameStats& stats() const override { return stats_; }
  [[nodiscard]] Backend backend() const override { return Backend::kCpu; }

 private:
  void bin(std::size_t K);
  // Calls fn(ty, tx0, tx1) for the tile rows of Gaussian k's bounding box and the
  // tiles of each its δ ellipse reaches (elongated ellipses leave many box tiles
  // untouched).
  template <class Fn>
  void for_each_band(std::size_t k, Fn&& fn) const {
    const int x0 = tile_lo_[k] & 0xffff, y0 = tile_lo_[k] >> 16, x1 = tile_hi_[k] & 0xffff, y1 = tile_hi_[k] >> 16;
    for_each_ellipse_band(rows_[k], y0, y1, kTileSize, kBinPad, [&](int ty, int c0, int c1) {
      if (c1 >= 0) fn(ty, std::max(x0, std::max(c0, 0) / kTileSize), std::min(x1, c1 / kTileSize));
    });
  }
  // Gaussian k's tile rows, kept when there are at most kStoredBands of them
  // (computed once in the parallel projection, read by both binning passes).
  void store_bands(std::size_t k) {
    const int y0 = tile_lo_[k] >> 16, y1 = tile_hi_[k] >> 16;
    if (y1 - y0 >= kStoredBands) return;
    TileBands& b = bands_[k];
    std::fill(std::begin(b.tx0), std::end(b.tx0), std::uint16_t{1});
    std::fill(std::begin(b.tx1), std::end(b.tx1), std::uint16_t{0});
    for_each_band(k, [&](int ty, int tx0, int tx1) {
      if (tx0 > tx1) return;
      b.tx0[ty - y0] = static_cast<std::uint16_t>(tx0);
      b.tx1[ty - y0] = static_cast<std::uint16_t>(tx1);
    });
  }
  [[nodiscard]] detail::TileFrame tile_frame(int tile) const;
  [[nodiscard]] detail::TileGaussians tile_gaussians(int tile) const;

  // The last forward (all reused between frames: no allocation once sizes settle).
  std::vector<float> params_;
  Intrinsics intrinsics_;
  CameraView view_;
  SplatSettings settings_;
  ViewParams<float> view_params_{};
  int tiles_x_ = 0, tiles_y_ = 0;
  std::vector<Splat2D<float>> splats_;
  std::vector<int> tile_lo_, tile_hi_;        // per Gaussian: tile rectangle packed (x0 | y0 << 16), (x1 | y1 << 16)
  std::vector<EllipseRows<float>> rows_;       // per Gaussian: its ellipse row by row, for binning
  static constexpr int kStoredBands = 8;
  struct TileBands {
    std::uint16_t tx0[kStoredBands], tx1[kStoredBands];  // tile columns per tile row (tx1 < tx0: none)
  };
  std::vector<TileBands> bands_;               // per Gaussian with at most kStoredBands tile rows
  std::vector<std::uint32_t> order_;          // visible Gaussians, amplitude descending
  std::vector<std::uint32_t> bucket_count_;
  std::vector<std::uint32_t> tile_offset_;    // tiles + 1
  std::vector<std::uint32_t> chunk_cursor_;   // per (chunk of order_, tile): entry count, then write cursor
  std::vector<std::uint32_t> entries_;        // Gaussian id per (tile, rank)
  std::vector<detail::PackedSplat> packed_;   // per Gaussian: its 2D parameters for the tile kernels
  std::vector<float> m_, S_, I_;              // per pixel
  std::vector<float> entry_grads_;            // 6 per entry
  std::vector<double> gaussian_grads_;        // 6 per Gaussian
  SplatFrameStats stats_;
};

void CpuSplatRenderer::forward(std::span<const float> params, const Intrinsics& K, const CameraView& view,
                               const SplatSettings& settings, std::span<float> image) {
  if (params.size() % kParams != 0) {
    throw std::invalid_argument("splat: parameter array of " + std::to_string(params.size()) +
                                " floats is not a multiple of 11");
  }
  const std::size_t pixels = static_cast<std::size_t>(K.width) * K.height;
  if (image.size() != pixels) throw std::invalid_argument("splat: image span does not match the intrinsics");
  params_.assign(params.begin(), params.end());
  intrinsics_ = K;
  view_ = view;
  settings_ = settings;
  view_params_ = make_splat_view<float>(K, view);
  const std::size_t count = params.size() / kParams;
  tiles_x_ = (K.width + kTileSize - 1) / kTileSize;
  tiles_y_ = (K.height + kTileSize - 1) / kTileSize;

  // 1. Project every Gaussian (Eq. 2-6) and find its tile rectangle.
  splats_.resize(count);
  packed_.resize(count);
  tile_lo_.resize(count);
  tile_hi_.resize(count);
  rows_.resize(count);
  bands_.resize(count);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, count, 1024), [&](const auto& range) {
    for (std::size_t k = range.begin(); k != range.end(); ++k) {
      Splat2D<float> s = project_gaussian(&params_[kParams * k], view_params_, settings.cutoff, settings.low_pass);
      if (s.visible) {
        // Pixels whose centres can lie in the ellipse's bounding box.
        // Clamped in float first so huge extents cannot overflow the int conversion.
        auto pixel = [](float x, int size) { return static_cast<int>(std::clamp(x, -1.0f, static_cast<float>(size))); };
        const int c0 = std::max(0, pixel(std::ceil(s.u - s.half_w - 0.5f), K.width) - 1);
        const int c1 = std::min(K.width - 1, pixel(std::floor(s.u + s.half_w - 0.5f), K.width) + 1);
        const int r0 = std::max(0, pixel(std::ceil(s.v - s.half_h - 0.5f), K.height) - 1);
        const int r1 = std::min(K.height - 1, pixel(std::floor(s.v + s.half_h - 0.5f), K.height) + 1);
        if (!std::isfinite(s.u) || !std::isfinite(s.v) || !std::isfinite(s.half_w) || !std::isfinite(s.half_h) ||
            c0 > c1 || r0 > r1) {
          s.visible = false;
        } else {
          tile_lo_[k] = (c0 / kTileSize) | ((r0 / kTileSize) << 16);
          tile_hi_[k] = (c1 / kTileSize) | ((r1 / kTileSize) << 16);
          rows_[k] = ellipse_rows(s, settings.cutoff, kBinWiden);
          store_bands(k);
        }
      }
      splats_[k] = s;
      detail::PackedSplat& p = packed_[k];
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
    }
  });
  bin(count);

  // 2. Rasterize the tiles.
  m_.resize(pixels);
  S_.resize(pixels);
  I_.resize(pixels);
  const int tiles = tiles_x_ * tiles_y_;
  std::vector<std::int64_t> skipped(static_cast<std::size_t>(tiles), 0);
  tbb::parallel_for(tbb::blocked_range<int>(0, tiles, 1), [&](const auto& range) {
    for (int t = range.begin(); t != range.end(); ++t) {
      detail::forward_tile(tile_frame(t), tile_gaussians(t), m_.data(), S_.data(), I_.data(), &skipped[t]);
    }
  });
  stats_.skipped_terms = 0;
  for (std::int64_t s : skipped) stats_.skipped_terms += s;
  std::copy(I_.begin(), I_.end(), image.begin());
}

// Counting sorts: visible Gaussians by amplitude (descending, ties by index) into
// order_, then (tile, order) pairs into entries_, and their 2D parameters gathered
// as one SoA block per tile.
void CpuSplatRenderer::bin(std::size_t K) {
  bucket_count_.assign(kAmplitudeBuckets + 1, 0);
  auto bucket_of = [](float a) {
    return kAmplitudeBuckets - 1 - std::clamp(static_cast<int>(a * kAmplitudeBuckets), 0, kAmplitudeBuckets - 1);
  };
  int visible = 0;
  for (std::size_t k = 0; k < K; ++k) {
    if (!splats_[k].visible) continue;
    ++bucket_count_[bucket_of(splats_[k].amplitude) + 1];
    ++visible;
  }
  for (int b = 0; b < kAmplitudeBuckets; ++b) bucket_count_[b + 1] += bucket_count_[b];
  order_.resize(static_cast<std::size_t>(visible));
  for (std::size_t k = 0; k < K; ++k) {
    if (splats_[k].visible) order_[bucket_count_[bucket_of(splats_[k].amplitude)]++] = static_cast<std::uint32_t>(k);
  }
  stats_.visible = visible;

  // (tile, order) pairs: order_ is cut into chunks that count their entries per tile
  // and then scatter them in parallel; offsets run tile-major, chunk-minor, so
  // entries_ is exactly what one serial pass would write (deterministic).
  const int tiles = tiles_x_ * tiles_y_;
  const int chunks = std::clamp(visible / 4096, 1, 32);
  chunk_cursor_.assign(static_cast<std::size_t>(chunks) * tiles, 0);
  auto chunk_range = [&](int c) {
    return std::pair<std::size_t, std::size_t>(static_cast<std::size_t>(visible) * c / chunks,
                                               static_cast<std::size_t>(visible) * (c + 1) / chunks);
  };
  // The tiles of a Gaussian's bounding-box rectangle that its δ ellipse reaches,
  // row band by row band (elongated ellipses leave many box tiles untouched).
  auto for_each_tile = [&](std::uint32_t k, auto&& fn) {
    const int y0 = tile_lo_[k] >> 16, y1 = tile_hi_[k] >> 16;
    if (y1 - y0 < kStoredBands) {
      const TileBands& b = bands_[k];
      for (int ty = y0; ty <= y1; ++ty) {
        for (int tx = b.tx0[ty - y0]; tx <= b.tx1[ty - y0]; ++tx) fn(ty * tiles_x_ + tx);
      }
    } else {
      for_each_band(k, [&](int ty, int tx0, int tx1) {
        for (int tx = tx0; tx <= tx1; ++tx) fn(ty * tiles_x_ + tx);
      });
    }
  };
  tbb::parallel_for(0, chunks, [&](int c) {
    std::uint32_t* count = chunk_cursor_.data() + static_cast<std::size_t>(c) * tiles;
    const auto [lo, hi] = chunk_range(c);
    for (std::size_t i = lo; i < hi; ++i) for_each_tile(order_[i], [&](int t) { ++count[t]; });
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
  stats_.tile_entries = static_cast<std::int64_t>(entries_.size()); if (getenv("KST")) fprintf(stderr, "entries %zu\n", entries_.size());
  tbb::parallel_for(0, chunks, [&](int c) {
    std::uint32_t* cursor = chunk_cursor_.data() + static_cast<std::size_t>(c) * tiles;
    const auto [lo, hi] = chunk_range(c);
    for (std::size_t i = lo; i < hi; ++i) {
      const std::uint32_t k = order_[i];
      for_each_tile(k, [&](int t) { entries_[cursor[t]++] = k; });
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
  f.beta = settings_.beta;
  f.cutoff = settings_.cutoff;
  f.skip_log_weight = settings_.skip_log_weight;
  f.soft = settings_.mode == MipMode::kSoft;
  f.count_skipped = f.soft && settings_.count_skipped;
  return f;
}

// The tile's entries (Gaussian ids) into the packed 2D parameters.
detail::TileGaussians CpuSplatRenderer::tile_gaussians(int tile) const {
  const std::uint32_t lo = tile_offset_[tile], n = tile_offset_[tile + 1] - lo;
  return {packed_.data(), entries_.data() + lo, static_cast<int>(n)};
}

void CpuSplatRenderer::backward(std::span<const float> dL_dimage, std::span<float> dL_dparams,
                                std::span<float> screen_grad) {
  if (settings_.mode != MipMode::kSoft) throw std::logic_error("splat: backward needs a soft-MIP forward");
  if (dL_dimage.size() != I_.size() || dL_dparams.size() != params_.size() ||
      (!screen_grad.empty() && screen_grad.size() != splats_.size())) {
    throw std::invalid_argument("splat: backward spans do not match the last forward");
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
  // 2. Combined per Gaussian in entry order (deterministic), in double.
  const std::size_t K = splats_.size();
  gaussian_grads_.assign(6 * K, 0.0);
  for (std::size_t e = 0; e < entries_.size(); ++e) {
    double* g = &gaussian_grads_[6 * static_cast<std::size_t>(entries_[e])];
    for (int i = 0; i < 6; ++i) g[i] += entry_grads_[6 * e + i];
  }
  // 3. Through the projection to the 11 parameters, in double (splat_math.hpp).
  const ViewParams<double> view = make_splat_view<double>(intrinsics_, view_);
  tbb::parallel_for(tbb::blocked_range<std::size_t>(0, K, 512), [&](const auto& range) {
    for (std::size_t k = range.begin(); k != range.end(); ++k) {
      if (!splats_[k].visible) continue;
      double p[kParams];
      for (int i = 0; i < kParams; ++i) p[i] = params_[kParams * k + i];
      ProjectionCache<double> cache;
      const Splat2D<double> s = project_gaussian(p, view, double(settings_.cutoff), double(settings_.low_pass), &cache);
      if (!s.visible) continue;
      const double* g6 = &gaussian_grads_[6 * k];
      Splat2DGrad<double> g{g6[0], g6[1], g6[2], g6[3], g6[4], g6[5]};
      double out[kParams] = {};
      project_gaussian_backward(p, view, cache, g, out);
      for (int i = 0; i < kParams; ++i) dL_dparams[kParams * k + i] += static_cast<float>(out[i]);
      if (!screen_grad.empty()) screen_grad[k] += static_cast<float>(std::hypot(g6[0], g6[1]));
    }
  });
}

}  // namespace

std::unique_ptr<SplatRenderer> make_cpu_splat_renderer() { return std::make_unique<CpuSplatRenderer>(); }

}  // namespace hisnegs::splat
