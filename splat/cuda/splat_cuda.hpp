// SPDX-License-Identifier: Apache-2.0
// Host interface of the CUDA splatting back end (splat/cuda/splat.cu): the same
// math as the CPU (splat/splat_math.hpp), 16x16 tiles, one thread block per tile.
// C++17 and no CUDA headers (nvcc compiles the .cu as C++17); the SplatRenderer
// adapter lives in splat/splat_renderer.cpp. Only built with the CUDA back end.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>

#include "splat/splat_math.hpp"

namespace hisnegs::splat::cuda {

class CudaSplatter {
 public:
  // Throws std::runtime_error when no device can be used.
  CudaSplatter();
  ~CudaSplatter();
  CudaSplatter(const CudaSplatter&) = delete;
  CudaSplatter& operator=(const CudaSplatter&) = delete;

  // Renders `count` Gaussians (host `params`, 11 floats each, gmf::GaussianParam
  // order) into host `image` (view.height x view.width floats), with host `floor`
  // (same size; null: none) as one more term per pixel. Keeps the device state for
  // backward(). Synchronous.
  void forward(const float* params, std::size_t count, const ViewParams<float>& view, const KernelSettings& settings,
               float* image, const float* floor = nullptr);
  // Soft mode: adds dL/dparams (11 x count, host) for host `dL_dimage` (H x W) of the
  // last forward; when `screen_grad` is not null also adds |dL/dμ2D| per Gaussian.
  void backward(const float* dL_dimage, float* dL_dparams, float* screen_grad);
  // The last forward's per-pixel softmax state (SplatRenderer::soft_state) into host
  // arrays of H x W floats each.
  void soft_state(float* m, float* S) const;

  [[nodiscard]] int visible() const;
  [[nodiscard]] std::int64_t tile_entries() const;
  [[nodiscard]] std::int64_t skipped_terms() const;
  // Milliseconds of the last forward's / backward's device work (CUDA events),
  // without the host<->device copies.
  [[nodiscard]] double last_forward_ms() const;
  [[nodiscard]] double last_backward_ms() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hisnegs::splat::cuda
