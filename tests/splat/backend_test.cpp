// SPDX-License-Identifier: Apache-2.0
// Back-end resolution: CPU always works; AUTO falls back to the CPU without a
// GPU; an explicit CUDA request without a device is a clear InputError.
#include "splat/backend.hpp"

#include <gtest/gtest.h>

#include "io/error.hpp"

namespace hisnegs::splat {
namespace {

TEST(Backend, ParsesRequests) {
  EXPECT_EQ(parse_backend_request("auto"), BackendRequest::kAuto);
  EXPECT_EQ(parse_backend_request("cpu"), BackendRequest::kCpu);
  EXPECT_EQ(parse_backend_request("cuda"), BackendRequest::kCuda);
  EXPECT_THROW((void)parse_backend_request("gpu"), io::InputError);
}

TEST(Backend, CpuRequestIsAlwaysCpu) { EXPECT_EQ(resolve_backend(BackendRequest::kCpu), Backend::kCpu); }

TEST(Backend, ProbeMatchesTheBuild) {
  const CudaDeviceInfo& info = cuda_device_info();
  EXPECT_EQ(info.compiled, HISNEGS_HAVE_CUDA == 1);
  if (!info.available) {
    EXPECT_FALSE(info.reason.empty());
  }
}

TEST(Backend, WithoutADeviceAutoIsCpuAndCudaIsAnError) {
  if (cuda_device_info().available) GTEST_SKIP() << "a CUDA device is present: " << cuda_device_info().name;
  EXPECT_EQ(resolve_backend(BackendRequest::kAuto), Backend::kCpu);
  EXPECT_THROW((void)resolve_backend(BackendRequest::kCuda), io::InputError);
}

TEST(Backend, WithADeviceAutoIsCuda) {
  if (!cuda_device_info().available) GTEST_SKIP() << "no CUDA device: " << cuda_device_info().reason;
  EXPECT_EQ(resolve_backend(BackendRequest::kAuto), Backend::kCuda);
}

}  // namespace
}  // namespace hisnegs::splat
