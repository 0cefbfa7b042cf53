#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The whole test suite under AddressSanitizer + UndefinedBehaviorSanitizer (the
# `asan` preset: GCC, -O1 -g1, CPU only; any report fails its test). CI runs it
# after the release suite (scripts/test.sh). Extra arguments go to ctest.
set -euo pipefail
HISNEGS_PRESET=asan exec bash "$(dirname "$0")/test.sh" "$@"
