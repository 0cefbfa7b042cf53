// SPDX-License-Identifier: Apache-2.0
// CUDA ground-truth MIPs: one thread per pixel over splat/raymarch_kernel.hpp,
// kRayBlock x kRayBlock thread blocks (a tile of rays shares bricks in cache).
#include <cuda_runtime.h>

#include <stdexcept>

#include "splat/cuda/check.cuh"
#include "splat/cuda/device_buffer.cuh"
#include "splat/cuda/raymarch_cuda.hpp"
#include "splat/raymarch_kernel.hpp"

namespace hisnegs::splat::cuda {
namespace {

// The side of a thread block of rays: 16 x 16 = 256 threads, a tile of neighbouring
// rays that read the same bricks.
constexpr int kRayBlock = 16;

__global__ void march_kernel(kernels::DenseVolume vol, kernels::BrickMax bricks, kernels::MarchParams mp,
                             kernels::RayView view, float* out) {
  const int col = blockIdx.x * blockDim.x + threadIdx.x;
  const int row = blockIdx.y * blockDim.y + threadIdx.y;
  if (col >= view.width || row >= view.height) return;
  out[row * view.width + col] = kernels::march_pixel(vol, bricks, mp, view, col, row);
}

}  // namespace

struct CudaRayMarcher::Impl {
  DeviceBuffer<float> voxels, brick_max, image;
  kernels::DenseVolume vol{};
  kernels::BrickMax bricks{};
  kernels::MarchParams params{};
  cudaEvent_t start = nullptr, stop = nullptr;
  double last_ms = 0;
};

CudaRayMarcher::CudaRayMarcher(const kernels::DenseVolume& volume, const kernels::BrickMax& bricks,
                               const kernels::MarchParams& params)
    : impl_(std::make_unique<Impl>()) {
  impl_->voxels.upload(volume.voxels, static_cast<std::size_t>(volume.nx) * volume.ny * volume.nz);
  impl_->brick_max.upload(bricks.max, static_cast<std::size_t>(bricks.bx) * bricks.by * bricks.bz);
  impl_->vol = {impl_->voxels.data(), volume.nx, volume.ny, volume.nz};
  impl_->bricks = {impl_->brick_max.data(), bricks.bx, bricks.by, bricks.bz};
  impl_->params = params;
  HISNEGS_CUDA_CHECK(cudaEventCreate(&impl_->start));
  HISNEGS_CUDA_CHECK(cudaEventCreate(&impl_->stop));
}

CudaRayMarcher::~CudaRayMarcher() {
  if (impl_->start) cudaEventDestroy(impl_->start);
  if (impl_->stop) cudaEventDestroy(impl_->stop);
}

void CudaRayMarcher::render(const kernels::RayView& vp, float* out, std::size_t count) {
  const std::size_t pixels = static_cast<std::size_t>(vp.width) * vp.height;
  if (count != pixels) throw std::invalid_argument("CudaRayMarcher::render: output has the wrong size");
  impl_->image.resize(pixels);
  const dim3 block(kRayBlock, kRayBlock);
  const dim3 grid((vp.width + kRayBlock - 1) / kRayBlock, (vp.height + kRayBlock - 1) / kRayBlock);
  HISNEGS_CUDA_CHECK(cudaEventRecord(impl_->start));
  march_kernel<<<grid, block>>>(impl_->vol, impl_->bricks, impl_->params, vp, impl_->image.data());
  HISNEGS_CUDA_CHECK_LAUNCH();
  HISNEGS_CUDA_CHECK(cudaEventRecord(impl_->stop));
  HISNEGS_CUDA_CHECK(cudaEventSynchronize(impl_->stop));
  float ms = 0;
  HISNEGS_CUDA_CHECK(cudaEventElapsedTime(&ms, impl_->start, impl_->stop));
  impl_->last_ms = ms;
  impl_->image.download(out, pixels);
}

double CudaRayMarcher::last_kernel_ms() const { return impl_->last_ms; }

}  // namespace hisnegs::splat::cuda
