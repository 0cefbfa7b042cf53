// SPDX-License-Identifier: Apache-2.0
// Back-end choice: cached CUDA probe and the one-time "using the CPU" notice.
#include "splat/backend.hpp"

#include <cstdio>
#include <mutex>

#include "io/error.hpp"
#if HISNEGS_HAVE_CUDA
#include "splat/cuda/device.hpp"
#endif

namespace hisnegs::splat {

std::string_view to_string(Backend backend) { return backend == Backend::kCuda ? "cuda" : "cpu"; }

BackendRequest parse_backend_request(std::string_view text, std::string_view option) {
  if (text == "auto") return BackendRequest::kAuto;
  if (text == "cpu") return BackendRequest::kCpu;
  if (text == "cuda") return BackendRequest::kCuda;
  throw io::InputError(std::string(option) + " = '" + std::string(text) + "': expected auto|cpu|cuda");
}

const CudaDeviceInfo& cuda_device_info() {
  static const CudaDeviceInfo info = [] {
#if HISNEGS_HAVE_CUDA
    return cuda::probe_devices();
#else
    CudaDeviceInfo none;
    none.reason = "this build has no CUDA back end (configured with HISNEGS_CUDA=OFF or without nvcc)";
    return none;
#endif
  }();
  return info;
}

Backend resolve_backend(BackendRequest request) {
  if (request == BackendRequest::kCpu) return Backend::kCpu;
  const CudaDeviceInfo& info = cuda_device_info();
  if (info.available) return Backend::kCuda;
  if (request == BackendRequest::kCuda) {
    throw io::InputError("--backend cuda: no usable CUDA device (" + info.reason + ")");
  }
  static std::once_flag notice;
  std::call_once(notice, [&] {
    std::fprintf(stderr, "hisnegs: no CUDA device (%s); using the CPU (TBB) back end\n", info.reason.c_str());
  });
  return Backend::kCpu;
}

}  // namespace hisnegs::splat
