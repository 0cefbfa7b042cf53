#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# Memory stability of a long training: trains a tiny scene (40x40x16
# synthetic stack, 24² ground truth, ~100 Gaussians) for EPOCHS epochs (default
# 2000) with `hisnegs train` and samples its resident memory (VmRSS) every
# INTERVAL seconds (default 0.25). Density control runs over the first 10% of the
# epochs; the samples after it are "steady". Prints a summary and writes
# OUT/rss.csv (seconds, epochs done, RSS KiB). Exits 1 if the steady RSS grows
# more than 5% (last steady sample over the first), 2 on a setup failure.
#   scripts/rss-stability.sh [EPOCHS] [OUT]      (needs a release build)
set -euo pipefail
cd "$(dirname "$0")/.."
epochs="${1:-2000}"
out="${2:-build/rss-stability}"
interval="${INTERVAL:-0.25}"
bin="${HISNEGS:-build/release/apps/hisnegs}"
[ -x "$bin" ] || { echo "rss-stability: $bin not found (build the release preset first)" >&2; exit 2; }
case "$epochs" in '' | *[!0-9]*) echo "rss-stability: EPOCHS '$epochs' is not a positive integer" >&2; exit 2 ;; esac
[ "$epochs" -ge 20 ] || { echo "rss-stability: EPOCHS $epochs: need at least 20" >&2; exit 2; }

rm -rf "$out"
mkdir -p "$out"
warm=$((epochs / 10))
every=$((warm / 4 > 0 ? warm / 4 : 1))
cat >"$out/train.yaml" <<EOF
train:
  epochs: $epochs
  beta_warmup_epochs: $warm
  densify_from: $every
  densify_every: $every
  densify_until: $warm
  max_gaussians: 400
  save_every: $((epochs / 10))
EOF
"$bin" -q synth -o "$out/s.tif" --shape 16,40,40
"$bin" -q fit "$out/s.tif" -o "$out/m.ply" --gaussians 100 --time-budget 3 --optimizer adam
"$bin" -q gt "$out/s.tif" -o "$out/gt" --orbit both --size 24 --backend cpu

"$bin" -q --config "$out/train.yaml" train --init "$out/m.ply" --data "$out/gt" -o "$out/run" --backend cpu &
pid=$!
echo "seconds,epochs,rss_kib" >"$out/rss.csv"
start=$(date +%s.%N)
while kill -0 "$pid" 2>/dev/null; do
  rss=$(awk '/^VmRSS:/ {print $2}' "/proc/$pid/status" 2>/dev/null || true)
  [ -n "$rss" ] || break
  done_epochs=0
  [ -f "$out/run/log.csv" ] && done_epochs=$(($(wc -l <"$out/run/log.csv") - 1))
  now=$(date +%s.%N)
  echo "$(awk -v a="$now" -v b="$start" 'BEGIN {printf "%.2f", a - b}'),$done_epochs,$rss" >>"$out/rss.csv"
  sleep "$interval"
done
wait "$pid" || { echo "rss-stability: training failed" >&2; exit 2; }

# Steady samples: after density control (epochs done > warm-up + 1).
awk -F, -v warm="$warm" -v total="$epochs" '
  NR == 1 { next }
  { if ($3 > peak) peak = $3 }
  $2 > warm + 1 && $2 < total { if (first == "") { first = $3; first_epoch = $2 } last = $3; last_epoch = $2;
                                if ($3 > steady_max) steady_max = $3; n++ }
  END {
    if (n < 10) { print "rss-stability: only " n " steady samples; use more epochs" > "/dev/stderr"; exit 2 }
    growth = 100 * (last - first) / first
    printf "rss-stability: %d epochs, %d steady samples (epochs %d..%d)\n", total, n, first_epoch, last_epoch
    printf "  RSS after warm-up %.1f MiB, at the end %.1f MiB, steady max %.1f MiB, peak %.1f MiB\n",
           first / 1024, last / 1024, steady_max / 1024, peak / 1024
    printf "  steady growth %+.2f%% (limit 5%%)\n", growth
    exit (growth > 5) ? 1 : 0
  }' "$out/rss.csv"
