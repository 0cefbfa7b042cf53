// SPDX-License-Identifier: Apache-2.0
// HISNEGS_CUDA_CHECK: every CUDA runtime call and kernel launch is checked and a
// failure throws std::runtime_error naming the call, file and line.
#pragma once

#include <cuda_runtime.h>

#include <stdexcept>
#include <string>

#define HISNEGS_CUDA_CHECK(call)                                                                    \
  do {                                                                                              \
    const cudaError_t hisnegs_err_ = (call);                                                        \
    if (hisnegs_err_ != cudaSuccess) {                                                              \
      throw std::runtime_error(std::string("CUDA error in ") + #call + " at " + __FILE__ + ":" +    \
                               std::to_string(__LINE__) + ": " + cudaGetErrorString(hisnegs_err_)); \
    }                                                                                               \
  } while (0)

// After a kernel launch: launch-configuration errors now, execution errors at the next sync.
#define HISNEGS_CUDA_CHECK_LAUNCH() HISNEGS_CUDA_CHECK(cudaGetLastError())
