#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Quick start, command 2: install what is missing, build everything (Release,
# tests on) and run the whole test suite with CTest. `.ci/run` calls exactly this.
# HISNEGS_PRESET picks another CMake preset (scripts/test-asan.sh: asan).
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${HISNEGS_PRESET:-release}"
bash scripts/install-deps.sh
cmake --preset "$preset" >/dev/null
cmake --build --preset "$preset"
ctest --preset "$preset" -j "$(nproc)" "$@"
