#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Fuzzes the six file readers with libFuzzer: builds the `fuzz` preset (clang 14,
# ASan + UBSan; installs clang and libclang-rt-14-dev if missing), writes the seed
# corpora (scripts/make-fuzz-corpus.sh) and runs each target RUNS executions
# (default 2000) on a scratch copy of its seeds, so runs never grow the repo.
# Exits non-zero if any target finds a crash, leak, sanitizer report or broken
# promise; the input is kept in build/fuzz/artifacts/. CI runs this with the default.
#   scripts/fuzz.sh [RUNS] [TARGET...]     TARGET: tiff ply cameras config vdb zarr (default all)
set -euo pipefail
cd "$(dirname "$0")/.."
runs="${1:-2000}"
shift || true
targets=("$@")
[ ${#targets[@]} -gt 0 ] || targets=(tiff ply cameras config vdb zarr)

bash scripts/install-deps.sh
missing=()
for p in clang libclang-rt-14-dev; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  sudo=""
  [ "$(id -u)" -eq 0 ] || sudo="sudo"
  echo "fuzz: installing ${missing[*]}"
  export DEBIAN_FRONTEND=noninteractive
  $sudo apt-get update -qq
  $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

cmake --preset fuzz >/dev/null
cmake --build --preset fuzz
bash scripts/make-fuzz-corpus.sh build/fuzz/corpus >/dev/null

mkdir -p build/fuzz/artifacts
failed=()
summary=()
for t in "${targets[@]}"; do
  work="build/fuzz/run/$t"
  rm -rf "$work"
  mkdir -p "$work"
  cp build/fuzz/corpus/"$t"/* "$work"/
  log="build/fuzz/run/$t.log"
  echo "fuzz: $t, $runs runs (log $log)"
  start=$(date +%s%N)
  # -seed: the same mutations on every run, so CI is repeatable. -timeout: one
  # input taking over 25 s is a finding (a hang); -rss_limit_mb: so is using over
  # 2 GiB (the readers cap what hostile headers may allocate).
  status=0
  LSAN_OPTIONS="suppressions=$PWD/fuzz/lsan.supp:print_suppressions=0" \
  "build/fuzz/fuzz/fuzz_$t" -runs="$runs" -seed=1 -dict="fuzz/$t.dict" -timeout=25 -rss_limit_mb=2048 \
    -print_final_stats=1 -artifact_prefix="build/fuzz/artifacts/$t-" "$work" >"$log" 2>&1 || status=$?
  ms=$(( ($(date +%s%N) - start) / 1000000 ))
  if [ "$status" -ne 0 ]; then
    failed+=("$t")
    tail -n 60 "$log" >&2
  fi
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log")
  execs="${execs:-0}"
  summary+=("$(printf '%-8s %9d execs %6d.%03d s %7d exec/s  corpus %5d files  exit %d' "$t" "$execs" \
    $((ms / 1000)) $((ms % 1000)) $((execs * 1000 / (ms + 1))) "$(find "$work" -type f | wc -l)" "$status")")
done
printf 'fuzz: %s\n' "${summary[@]}"
if [ ${#failed[@]} -gt 0 ]; then
  echo "fuzz: FAILED: ${failed[*]} (inputs in build/fuzz/artifacts/)" >&2
  exit 1
fi
