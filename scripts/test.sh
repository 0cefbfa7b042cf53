#!/usr/bin/env bash
# Quick start, command 2: install what is missing, build everything (Release,
# tests on) and run the whole test suite with CTest. `.ci/run` calls exactly this.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake --preset release >/dev/null
cmake --build --preset release
ctest --preset release -j "$(nproc)" "$@"
