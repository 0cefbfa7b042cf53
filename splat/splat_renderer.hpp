// SPDX-License-Identifier: Apache-2.0
// The soft/hard-MIP splatting renderer behind one interface (TBB or CUDA back end)
// and the per-frame settings; the math is splat/splat_math.hpp, the double
// reference splat/splat_reference.hpp. No Gaussian storage of its own beyond a frame.
#pragma once

#include <cstdint>
#include <memory>
#include <span>

#include "gmf/core/gaussian_mixture.hpp"
#include "splat/backend.hpp"
#include "splat/camera.hpp"
#include "splat/splat_math.hpp"
#include "splat/splat_options.hpp"

namespace hisnegs::splat {

// The frame settings (splat_math.hpp's KernelSettings) made from the config section.
struct SplatSettings : KernelSettings {
  static SplatSettings from(const SplatOptions& options);
  // The background's MIP per pixel (splat/background_floor.hpp; H × W, row-major),
  // or empty for none: the image is max(splat, floor) in both modes (hard: the
  // floor is one more term of the max, which also culls Gaussians below it). Soft
  // mode combines by the max too, not inside Eq. 8's softmax: where every term is
  // dim (β g ≈ 1) the soft MIP is an average, and the dozens of ~0 tails a pixel of
  // background sees would pull a floor inside the softmax to a fraction of itself
  // (noisy op1: 39.2 dB inside, 40.1 dB by the max). The floor takes no gradient, and
  // none flows to the Gaussians where it is above their soft MIP. Read during
  // forward() only; the caller keeps it alive.
  std::span<const float> floor;
};

// Counters of the last forward (for benchmarks, `render` and tests).
struct SplatFrameStats {
  int visible = 0;                 // Gaussians in front of the camera whose ellipse meets the image
  std::int64_t tile_entries = 0;   // (Gaussian, tile) pairs rasterized
  std::int64_t skipped_terms = 0;  // soft-MIP (pixel, Gaussian) terms skipped by skip_log_weight
                                   // (only with SplatSettings::count_skipped, else 0)
};

// World->camera parameters of a view in the kernels' form.
template <class T>
ViewParams<T> make_splat_view(const Intrinsics& K, const CameraView& view);

class SplatRenderer {
 public:
  virtual ~SplatRenderer() = default;
  // Renders the K Gaussians in `params` (11 K floats, gmf::GaussianParam order) into
  // `image` (K.height x K.width floats, row-major). Keeps what backward() needs until
  // the next forward(). Hard mode is the max over the touching Gaussians.
  virtual void forward(std::span<const float> params, const Intrinsics& K, const CameraView& view,
                       const SplatSettings& settings, std::span<float> image) = 0;
  // Adds dL/dparams (11 K) for the loss gradient `dL_dimage` (H x W) of the last
  // forward: soft mode, or hard mode with KernelSettings::keep_argmax, whose
  // gradient is the max's subgradient (each pixel's argmax Gaussian alone). When `screen_grad` is not empty (K floats) it adds each
  // Gaussian's |dL/dμ2D| (pixels) for density control.
  virtual void backward(std::span<const float> dL_dimage, std::span<float> dL_dparams,
                        std::span<float> screen_grad = {}) = 0;
  // Soft mode: the last forward's softmax state per pixel (H x W each), its image
  // (before any floor) being Σ e^{βg − m} g / S over the terms: m = β × the largest
  // g that reaches the pixel (−∞ where none does) and S = Σ e^{βg − m} (0 there).
  // The renders of disjoint sets of Gaussians merge into their union's with
  // merge_soft_pixel (render_views.hpp), which is how several processes render one
  // model. Throws std::logic_error after a hard forward or none.
  virtual void soft_state(std::span<float> m, std::span<float> S) const = 0;
  [[nodiscard]] virtual const SplatFrameStats& stats() const = 0;
  [[nodiscard]] virtual Backend backend() const = 0;
};

// The TBB back end, or CUDA (throws io::InputError when this build or machine has none).
std::unique_ptr<SplatRenderer> make_splat_renderer(Backend backend);

// A mixture's parameters as the renderer reads them (gmf/core/gaussian_mixture.hpp).
using gmf::flat_params;

}  // namespace hisnegs::splat
