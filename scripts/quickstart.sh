#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Quick start, command 1: install what is missing, build (Release), and run the
# main job on the bundled default data: `hisnegs demo -o out/demo`. The Python
# module is built too where Python 3 with NumPy and pybind11 is found.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/install-deps.sh
cmake --preset release >/dev/null
targets=(hisnegs)
# The Python module too, where CMake found Python 3 with NumPy and pybind11.
info=build/release/python/hisnegs/_build_info.py
if [ -f "$info" ]; then targets+=(hisnegs_python); fi
cmake --build --preset release --target "${targets[@]}"
./build/release/apps/hisnegs demo -o out/demo "$@"
if [ -f "$info" ]; then
  python=$(sed -n 's/^PYTHON = "\(.*\)"$/\1/p' "$info")
  echo "quickstart: the Python module is built for $python: PYTHONPATH=build/release/python $python"
fi
