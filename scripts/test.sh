#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Quick start, command 2: install what is missing, build everything (Release,
# tests on), run clang-tidy on the sources changed since the last clean full pass
# (scripts/tidy.sh; HISNEGS_TIDY=0 skips it) and the whole test suite with CTest.
# `.ci/run` calls exactly this.
# HISNEGS_PRESET picks another CMake preset (scripts/test-asan.sh: asan).
set -euo pipefail
cd "$(dirname "$0")/.."
preset="${HISNEGS_PRESET:-release}"
bash scripts/install-deps.sh
cmake --preset "$preset" >/dev/null
cmake --build --preset "$preset"
if [ "${HISNEGS_TIDY:-1}" != 0 ] && [ "$preset" = release ]; then bash scripts/tidy.sh; fi
ctest --preset "$preset" -j "$(nproc)" "$@"
