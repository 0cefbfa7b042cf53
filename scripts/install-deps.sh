#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Installs the Debian packages hisnegs builds against, only those missing
# (idempotent: a second run installs nothing and does not touch apt's lists).
# Needs root (or sudo). CUDA is optional and never installed here: the build
# uses nvcc when it is on the machine.
set -euo pipefail

packages=(
  build-essential cmake ninja-build pkg-config
  libeigen3-dev libceres-dev libopenvdb-dev libboost-iostreams-dev libtbb-dev
  libtiff-dev libhdf5-dev libpng-dev libgif-dev libhwy-dev libzstd-dev zlib1g-dev libblosc-dev
  libcli11-dev libyaml-cpp-dev nlohmann-json3-dev libcpp-httplib-dev
  libgtest-dev libgmock-dev libbenchmark-dev
  libopenvdb-tools python3-openvdb
  chromium  # tests/apps/cli/cli_viewer_test.cpp renders `export html` pages headless
  xz-utils  # scripts/device-bundle.sh packs the GPU bundle with xz
  python3-tifffile  # tests/io/tiff_stack_test.cpp reads the stacks hisnegs writes with tifffile
  python3-h5py  # tests/io/hdf5_stack_test.cpp reads the HDF5 stacks hisnegs writes with h5py
  python3-zarr  # tests/io/zarr_stack_test.cpp: Zarr fixtures written, and pyramids read back, by zarr-python
  libopenmpi-dev openmpi-bin  # optional at build time: fit and gt on MPI ranks (tests/apps/cli/cli_mpi_test.cpp)
  python3-dev python3-numpy pybind11-dev  # optional at build time: the Python module (apps/python)
  python3-pytest python3-scipy  # tests/python: pytest, and scipy.optimize driving hisnegs.Objective
  clang-tidy  # scripts/tidy.sh, run by scripts/test.sh (.clang-tidy)
)

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

sudo=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
    echo "install-deps: need root to install: ${missing[*]}" >&2
    exit 1
  fi
fi
echo "install-deps: installing ${missing[*]}"
export DEBIAN_FRONTEND=noninteractive
$sudo apt-get update -qq
$sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
