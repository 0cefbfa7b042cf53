// SPDX-License-Identifier: Apache-2.0
// Host-side declarations of the CUDA device probe (implemented in device.cu
// only when the CUDA back end is built). No CUDA headers here.
#pragma once

#include "splat/backend.hpp"

namespace hisnegs::splat::cuda {

// Queries the CUDA runtime; never throws (errors go to info.reason).
CudaDeviceInfo probe_devices();

}  // namespace hisnegs::splat::cuda
