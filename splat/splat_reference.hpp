// SPDX-License-Identifier: Apache-2.0
// The definition of soft/hard-MIP splatting in double precision, pixel by pixel
// over every Gaussian, with its exact backward: what the tests check the TBB and
// CUDA back ends against. Slow by design (O(pixels × K)); no tiles, no skipping.
#pragma once

#include <span>
#include <vector>

#include "splat/splat_renderer.hpp"

namespace hisnegs::splat {

// Image (H x W, row-major) of the Gaussians `params` (11 K doubles) in `view`, the
// max with settings.floor (if any) per pixel.
std::vector<double> render_reference(std::span<const double> params, const ViewParams<double>& view,
                                     const SplatSettings& settings);

// dL/dparams (11 K) for dL/dimage: soft mode, or the hard mode's subgradient (the
// first largest term of a pixel alone, none where the floor is at least it; the CPU
// back end orders equal terms otherwise: ties, of measure zero, may differ). When `screen_grad` is not null it
// receives |dL/dμ2D| per Gaussian.
std::vector<double> render_reference_backward(std::span<const double> params, const ViewParams<double>& view,
                                              const SplatSettings& settings, std::span<const double> dL_dimage,
                                              std::vector<double>* screen_grad = nullptr);

}  // namespace hisnegs::splat
