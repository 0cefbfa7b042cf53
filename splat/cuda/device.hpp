// SPDX-License-Identifier: Apache-2.0
// Host-side declarations of the CUDA device probe (implemented in device.cu
// only when the CUDA back end is built). No CUDA headers here.
#pragma once

#include <cstddef>
#include <string>

namespace hisnegs::splat {

// What the CUDA runtime says about the machine (splat::cuda_device_info() caches it).
struct CudaDeviceInfo {
  bool compiled = false;   // this build has the CUDA back end
  bool available = false;  // a device can be used now
  int device_count = 0;
  std::string name;  // device 0
  int compute_major = 0, compute_minor = 0;
  std::size_t memory_bytes = 0;
  std::string reason;  // why not available (driver message), empty if available
};

}  // namespace hisnegs::splat

namespace hisnegs::splat::cuda {

// Queries the CUDA runtime; never throws (errors go to info.reason).
CudaDeviceInfo probe_devices();

}  // namespace hisnegs::splat::cuda
