// SPDX-License-Identifier: Apache-2.0
// Host interface of the CUDA ground-truth ray marcher (splat/cuda/raymarch.cu):
// the same kernel as the CPU (splat/raymarch_kernel.hpp), one thread per pixel.
// Only declared when the CUDA back end is built. No CUDA headers here; C++17.
#pragma once

#include <cstddef>
#include <memory>

#include "splat/raymarch_kernel.hpp"

namespace hisnegs::splat::cuda {

class CudaRayMarcher {
 public:
  // Uploads the volume and brick maxima (host pointers, as RayMarcher prepares
  // them). Throws std::runtime_error on any CUDA error (no device, out of memory).
  CudaRayMarcher(const kernels::DenseVolume& volume, const kernels::BrickMax& bricks,
                 const kernels::MarchParams& params);
  ~CudaRayMarcher();
  CudaRayMarcher(const CudaRayMarcher&) = delete;
  CudaRayMarcher& operator=(const CudaRayMarcher&) = delete;

  // Renders `view` into host memory `out` (`count` = height × width floats). Synchronous.
  // (Pointer + count, not std::span: this header is compiled as C++17 by nvcc.)
  void render(const kernels::RayView& view, float* out, std::size_t count);
  // Milliseconds of the last render's kernel alone (CUDA events), without the copy back.
  [[nodiscard]] double last_kernel_ms() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace hisnegs::splat::cuda
