// SPDX-License-Identifier: Apache-2.0
// Which compute back end runs rendering and training: the TBB CPU back end or
// CUDA. Probes the CUDA runtime once; without a usable GPU the CPU back end is
// chosen and a single notice says so. Knows nothing of what the back ends do.
#pragma once

#include <cstddef>
#include <string>
#include <string_view>

#include "splat/cuda/device.hpp"  // CudaDeviceInfo

namespace hisnegs::splat {

enum class Backend { kCpu, kCuda };
enum class BackendRequest { kAuto, kCpu, kCuda };
[[nodiscard]] std::string_view to_string(Backend backend);
// Parses "auto" | "cpu" | "cuda"; throws io::InputError naming `option` otherwise.
[[nodiscard]] BackendRequest parse_backend_request(std::string_view text, std::string_view option = "--backend");

// Probed once per process (thread-safe), cached afterwards.
[[nodiscard]] const CudaDeviceInfo& cuda_device_info();

// kAuto: CUDA when available, else CPU (printing one notice to stderr per process).
// kCuda without a device: throws io::InputError explaining why. kCpu: CPU.
[[nodiscard]] Backend resolve_backend(BackendRequest request);

}  // namespace hisnegs::splat
