// SPDX-License-Identifier: Apache-2.0
// CUDA device probe: device count, name, compute capability and memory of device 0.
#include <cuda_runtime.h>

#include "splat/cuda/device.hpp"

namespace hisnegs::splat::cuda {

CudaDeviceInfo probe_devices() {
  CudaDeviceInfo info;
  info.compiled = true;
  int count = 0;
  const cudaError_t err = cudaGetDeviceCount(&count);
  if (err != cudaSuccess) {
    info.reason = cudaGetErrorString(err);
    cudaGetLastError();  // clear the sticky error state
    return info;
  }
  info.device_count = count;
  if (count == 0) {
    info.reason = "no CUDA device found";
    return info;
  }
  cudaDeviceProp prop{};
  if (cudaGetDeviceProperties(&prop, 0) != cudaSuccess) {
    info.reason = "cannot query device 0";
    return info;
  }
  info.available = true;
  info.name = prop.name;
  info.compute_major = prop.major;
  info.compute_minor = prop.minor;
  info.memory_bytes = prop.totalGlobalMem;
  return info;
}

}  // namespace hisnegs::splat::cuda
