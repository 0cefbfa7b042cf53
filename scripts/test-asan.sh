#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The test suite under AddressSanitizer + UndefinedBehaviorSanitizer (the `asan`
# preset: GCC, -O1 -g1, CPU only; any report fails its test). CI runs it after the
# release suite (scripts/test.sh). Extra arguments go to ctest.
#
# Left out by default (they run in the release suite): the end-to-end pipeline
# runs, which repeat under ASan the same code the unit and CLI tests already cover
# there, at 3-4x the release time each (whole `run`/`demo`/`compare`/`bench`
# pipelines, crash-and-resume training). HISNEGS_ASAN_ALL=1 runs everything.
set -euo pipefail
slow='^(CliCompare|CliBench|CliDemo|RunPipeline|CrashSafeTraining)\.'
if [ "${HISNEGS_ASAN_ALL:-0}" = 1 ] || [ $# -gt 0 ]; then
  HISNEGS_PRESET=asan exec bash "$(dirname "$0")/test.sh" "$@"
fi
HISNEGS_PRESET=asan exec bash "$(dirname "$0")/test.sh" -E "$slow"
