# SPDX-License-Identifier: Apache-2.0
# Decides whether the CUDA back end is built (HISNEGS_CUDA = AUTO | ON | OFF).
# Targets sm_90 (H100/H200) natively plus compute_75 PTX that the driver JITs on
# any newer GPU, so one binary runs wherever a GPU is present.
include(CheckLanguage)
include(HisnegsOption)
hisnegs_tristate(HISNEGS_CUDA "Build the CUDA back end: AUTO (when nvcc is found), ON or OFF")
set(_hisnegs_cuda ${_HISNEGS_CUDA_MODE})
set(HISNEGS_HAVE_CUDA OFF)
if(NOT _hisnegs_cuda STREQUAL "OFF")
  check_language(CUDA)
  if(CMAKE_CUDA_COMPILER)
    if(NOT DEFINED CMAKE_CUDA_ARCHITECTURES)
      set(CMAKE_CUDA_ARCHITECTURES "90-real;75-virtual")
    endif()
    # .cu files are C++17: CMake 3.25 cannot ask nvcc for C++20 (and would otherwise
    # inherit CXX_STANDARD 20 and fail). Device code and the headers it includes
    # (splat/*_kernel.hpp, splat/cuda/*) are written to C++17.
    set(CMAKE_CUDA_STANDARD 17)
    set(CMAKE_CUDA_STANDARD_REQUIRED ON)
    enable_language(CUDA)
    find_package(CUDAToolkit REQUIRED)
    set(HISNEGS_HAVE_CUDA ON)
  elseif(_hisnegs_cuda STREQUAL "ON")
    message(FATAL_ERROR "HISNEGS_CUDA=ON but no CUDA compiler (nvcc) was found")
  endif()
endif()
message(STATUS "hisnegs: CUDA back end ${HISNEGS_HAVE_CUDA}")
