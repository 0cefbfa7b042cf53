# SPDX-License-Identifier: Apache-2.0
# All third-party packages, from Debian. Order matters: TBB's own config and
# Ceres (whose SuiteSparse lookup loads TBB) must come before OpenVDB, whose
# bundled FindTBB.cmake would otherwise define TBB::tbb half-way.
find_package(Threads REQUIRED)
find_package(TBB CONFIG REQUIRED)
find_package(Eigen3 3.4 REQUIRED NO_MODULE)
find_package(Ceres REQUIRED)
find_path(HISNEGS_OPENVDB_CMAKE_DIR FindOpenVDB.cmake
  PATHS /usr/lib/x86_64-linux-gnu/cmake/OpenVDB /usr/lib/cmake/OpenVDB /usr/local/lib/cmake/OpenVDB
        /usr/lib/aarch64-linux-gnu/cmake/OpenVDB)
if(HISNEGS_OPENVDB_CMAKE_DIR)
  list(APPEND CMAKE_MODULE_PATH ${HISNEGS_OPENVDB_CMAKE_DIR})
endif()
find_package(OpenVDB REQUIRED)
find_package(TIFF REQUIRED)
find_package(PNG REQUIRED)
find_package(GIF REQUIRED)
# zlib (zlib1g-dev): the compact checkpoint's CRC-32.
find_package(ZLIB REQUIRED)
find_package(CLI11 CONFIG REQUIRED)
find_package(yaml-cpp CONFIG REQUIRED)
find_package(nlohmann_json 3 CONFIG REQUIRED)
find_package(hwy CONFIG REQUIRED)
find_package(benchmark CONFIG REQUIRED)
# zstd (libzstd-dev) for the compact checkpoint; Debian's package ships a
# pkg-config file on every release, its CMake config only on newer ones.
find_package(PkgConfig REQUIRED)
pkg_check_modules(ZSTD REQUIRED IMPORTED_TARGET libzstd)
# blosc (libblosc-dev): OME-Zarr chunks (io/zarr_codecs.cpp).
pkg_check_modules(BLOSC REQUIRED IMPORTED_TARGET blosc)
# cpp-httplib (libcpp-httplib-dev; Debian builds it as a shared library) for `hisnegs view`.
pkg_check_modules(HTTPLIB REQUIRED IMPORTED_TARGET cpp-httplib)
# HDF5 (libhdf5-dev, the serial C library): BigDataViewer, Imaris and plain HDF5
# stacks. Through its pkg-config file: CMake's FindHDF5 needs the C language enabled.
pkg_check_modules(HDF5 REQUIRED IMPORTED_TARGET hdf5)
if(BUILD_TESTING)
  find_package(GTest CONFIG REQUIRED)
endif()
