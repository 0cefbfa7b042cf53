#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Quick start, command 1: install what is missing, build (Release), and run the
# main job on the bundled default data: `hisnegs demo -o out/demo`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake --preset release >/dev/null
cmake --build --preset release --target hisnegs
./build/release/apps/hisnegs demo -o out/demo "$@"
