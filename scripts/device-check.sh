#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# The one call to make on a GPU machine, from the bundle of scripts/device-bundle.sh
# (docs/benchmarks.md, "Running on a GPU"):
#
#   bash .device/device-check.sh OUTDIR        (or with $OUT set: writes under $OUT)
#
# In order, each step bounded by `timeout`, every figure written under OUTDIR:
#   1. nvidia-smi once (model, driver)                          nvidia-smi.txt
#   2. the CUDA tests (and the back-end choice tests)           tests.txt
#   3. bench render, CUDA, K = 50k at 256² and 1024²            render.json
#   4. bench gt, CUDA, 256² and 1024²                           gt.json
#   5. a 2-epoch training run, CUDA (synthetic stack)           train/ (log.csv), train.txt
#   6. op1 (when bundled): a 30 s fit, then 50 epochs of the
#      default (GPU) schedule, projected to 2000                op1/ (log.csv), op1.txt
#   7. bench report --backend cuda                              report/
# then a short table (summary.txt). Exit status: non-zero if a CUDA test failed
# (or no GPU was usable); the benchmarks' own failures are reported in the table.
# Each step has its own limit; together at most about 12 minutes, and under 7
# on an H100/H200 as planned (15 minutes of device time per session).
set -uo pipefail
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
out=${1:-${OUT:-}}
[[ -n "$out" ]] || { echo "usage: device-check.sh OUTDIR (or set \$OUT)" >&2; exit 2; }
mkdir -p "$out"
out=$(cd "$out" && pwd)
# From .device/ (the bundle) or from scripts/ of a checkout with a bundle built.
if [[ -f "$here/env.sh" ]]; then bundle=$here; else bundle=$here/../.device; fi
[[ -f "$bundle/env.sh" ]] || { echo "device-check: no bundle at $bundle: run scripts/device-bundle.sh first" >&2; exit 2; }
H="$bundle/hisnegs"
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
start=$SECONDS
log() { echo "device-check: [$((SECONDS - start)) s] $*"; }
declare -A result

log "1. nvidia-smi"
if nvidia-smi --query-gpu=name,driver_version,memory.total,compute_cap --format=csv >"$out/nvidia-smi.txt" 2>&1; then
  gpu=$(sed -n 2p "$out/nvidia-smi.txt")
  nvidia-smi >>"$out/nvidia-smi.txt" 2>&1
else
  gpu="nvidia-smi failed: $(head -1 "$out/nvidia-smi.txt")"
fi
log "GPU: $gpu"
cat "$bundle/root/VERSION" 2>/dev/null >"$out/bundle-version.txt" || true

log "2. CUDA tests"
timeout 200 "$bundle/run-tests" --gtest_filter='*Cuda*:*cuda*:*CUDA*:Backend.*' >"$out/tests.txt" 2>&1
tests_status=$?
cp "$bundle/root/VERSION" "$out/bundle-version.txt" 2>/dev/null || true
passed=$(grep -c '^\[  PASSED  \]' "$out/tests.txt" || true)
failed=$(grep -E '^\[  FAILED  \] [A-Za-z]' "$out/tests.txt" | sort -u | wc -l)
skipped=$(grep -c '^\[  SKIPPED \] [A-Za-z]' "$out/tests.txt" || true)
result[tests]="exit $tests_status; failed $failed, skipped $skipped"
if grep -q "no CUDA device" "$out/tests.txt"; then result[tests]+=" (the tests saw no CUDA device)"; fi
log "tests: ${result[tests]}"

bench() {  # name timeout args...
  local name=$1 limit=$2
  shift 2
  timeout "$limit" "$H" bench "$@" --benchmark_out="$out/$name.json" --benchmark_out_format=json \
    >"$out/$name.txt" 2>&1
  echo $?
}
log "3. bench render (CUDA, K = 50k, 256² and 1024²)"
result[render]="exit $(bench render 90 render --sizes 256 1024 --gaussians 50000 --benchmark_filter='render/cuda/.*/K50000/')"
log "4. bench gt (CUDA, 256² and 1024²)"
result[gt]="exit $(bench gt 90 gt --sizes 256 1024 --benchmark_filter='gt/cuda/')"

log "5. 2-epoch training (CUDA)"
cat >"$work/short.yaml" <<'EOF'
gmf:
  time_budget_s: 10
  gaussians: 5000
train:
  save_every: 1000
EOF
(
  set -e
  "$H" -q synth -o "$work/synth.tif"
  "$H" -q gt "$work/synth.tif" -o "$work/gt" --orbit both --backend cuda
  "$H" -q --config "$work/short.yaml" fit "$work/synth.tif" -o "$work/init.ply"
  time "$H" --config "$work/short.yaml" train --init "$work/init.ply" --data "$work/gt" \
    -o "$out/train" --backend cuda --epochs 2
) >"$out/train.txt" 2>&1
result[train]="exit $?; $(tail -3 "$out/train/log.csv" 2>/dev/null | tr '\n' ' ')"

if [[ -f "$bundle/root/data/op1_neuron.tif" ]]; then
  log "6. op1: 50 epochs of the default GPU schedule"
  (
    set -e
    "$H" -q gt "$bundle/root/data/op1_neuron.tif" -o "$work/op1gt" --orbit both --backend cuda
    printf 'gmf:\n  time_budget_s: 30\n' >"$work/op1.yaml"
    "$H" -q --config "$work/op1.yaml" fit "$bundle/root/data/op1_neuron.tif" -o "$work/op1.ply"
    timeout 150 "$H" train --init "$work/op1.ply" --data "$work/op1gt" -o "$out/op1" --backend cuda --epochs 50
    "$H" eval --model "$out/op1/final.ply" --data "$work/op1gt/eval" --backend cuda -o "$out/op1/eval"
  ) >"$out/op1.txt" 2>&1
  status=$?
  per_epoch=$(awk -F, 'NR > 2 {n++; s = $2} NR == 2 {s0 = $2} END {if (n > 0) printf "%.3f", (s - s0) / n}' \
    "$out/op1/log.csv" 2>/dev/null)
  result[op1]="exit $status; ${per_epoch:-?} s/epoch -> 2000 epochs ~ $(awk -v p="${per_epoch:-0}" 'BEGIN {printf "%.0f", 2000 * p}') s"
else
  result[op1]="skipped (op1 not in the bundle)"
fi

log "7. bench report --backend cuda"
timeout 120 "$H" bench report --backend cuda -o "$out/report" --seconds-per-case 1 >"$out/report.txt" 2>&1
result[report]="exit $?"

# The short table: median ms per case from the Google Benchmark JSON.
table() {
  python3 - "$1" <<'EOF' 2>/dev/null || echo "  (no JSON: see the .txt beside it)"
import json, sys
for b in json.load(open(sys.argv[1])).get("benchmarks", []):
    if b.get("run_type") == "aggregate" and b.get("aggregate_name") != "median":
        continue
    print(f"  {b['name']:<60} {b['real_time']:10.3f} {b.get('time_unit', '')}")
EOF
}
{
  echo "hisnegs device check, $(date -u +%Y-%m-%dT%H:%M:%SZ), $((SECONDS - start)) s"
  echo "GPU: $gpu"
  echo "bundle: $(tr '\n' ' ' <"$out/bundle-version.txt" 2>/dev/null)"
  for k in tests render gt train op1 report; do printf '%-8s %s\n' "$k" "${result[$k]}"; done
  echo "render (CUDA):"
  table "$out/render.json"
  echo "gt (CUDA):"
  table "$out/gt.json"
} | tee "$out/summary.txt"
((tests_status == 0))
