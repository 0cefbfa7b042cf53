#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Checks the GPU bundle on this (GPU-less) machine: packs the existing CUDA build
# (scripts/device-bundle.sh, which fails over 64 MiB), then runs the bundled tests
# from a copy of .device/ somewhere else with a clean environment: every CUDA test
# must skip and nothing may fail, and the bundled hisnegs must say it has no GPU.
set -euo pipefail
cd "$(dirname "$0")/.."
HISNEGS_BUNDLE_SKIP_BUILD=${HISNEGS_BUNDLE_SKIP_BUILD:-1} bash scripts/device-bundle.sh
copy=$(mktemp -d)
trap 'rm -rf "$copy"' EXIT
cp -r .device "$copy/"
env -i HOME="$HOME" PATH=/usr/bin:/bin bash "$copy/.device/run-tests" \
  --gtest_filter='*Cuda*:*cuda*:*CUDA*:Backend.*:MaxMixture.*:AppConfig.*:Cli.HelpListsCommandsAndExitsZero' | tee "$copy/tests.txt"
if grep -q '^\[  FAILED  \]' "$copy/tests.txt"; then
  echo "test-device-bundle: a bundled test failed" >&2
  exit 1
fi
env -i HOME="$HOME" PATH=/usr/bin:/bin "$copy/.device/hisnegs" --version
echo "test-device-bundle: the bundle runs here with the CUDA tests skipping"
