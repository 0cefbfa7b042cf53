// SPDX-License-Identifier: Apache-2.0
// HISNEGS_HD marks math shared by the CPU and CUDA back ends: inline
// __host__ __device__ under nvcc, plain inline elsewhere.
#pragma once

#if defined(__CUDACC__)
#define HISNEGS_HD __host__ __device__ __forceinline__
#else
#define HISNEGS_HD inline
#endif
