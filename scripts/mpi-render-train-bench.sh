#!/usr/bin/env bash
# SPDX-License-Identifier: Apache-2.0
# 1 process on 1 core vs 2 MPI ranks bound to a core each: `render` (hard and soft)
# and 5 epochs of `train` (4 views per step) of a model on a ground-truth set
# (docs/benchmarks.md "Render and training on 2 ranks").
#
# Usage: bash scripts/mpi-render-train-bench.sh MODEL.ply GTSET_DIR WORKDIR
#   e.g. MODEL = op1's fit, GTSET_DIR = `hisnegs gt op1 -o GT --orbit eval`'s GT
set -uo pipefail
[[ $# -eq 3 ]] || { echo "usage: $0 MODEL.ply GTSET_DIR WORKDIR" >&2; exit 2; }
H=${HISNEGS:-$(cd "$(dirname "$0")/.." && pwd)/build/release/apps/hisnegs}
model=$(realpath "$1"); views=$(realpath "$2"); mkdir -p "$3"; cd "$3"
printf 'train: {epochs: 5, views_per_step: 4, save_every: 5, lr_initial: 0.0003, beta_start: 50, beta_warmup_epochs: 0}\n' > train.yaml
rm -rf r1hard r2hard r1soft r2soft t1 t2
# seconds LOG COMMAND...: runs COMMAND with its output in LOG, prints its wall time
seconds() { local log=$1 s e; shift; s=$(date +%s.%N); "$@" > "$log" 2>&1; e=$(date +%s.%N); echo "$e - $s" | bc; }
for mode in hard soft; do
  t=$(seconds r1$mode.log taskset -c 0 "$H" render --model "$model" --cameras "$views/cameras.json" -o r1$mode --mode $mode --backend cpu)
  echo "render $mode, 1 core: $t s; $(grep -o 'median [0-9.]* ms/view' r1$mode.log)"
  t=$(seconds r2$mode.log mpirun --allow-run-as-root -np 2 --bind-to core "$H" render --model "$model" --cameras "$views/cameras.json" -o r2$mode --mode $mode --backend cpu)
  echo "render $mode, 2 ranks: $t s; $(grep -o 'median [0-9.]* ms/view' r2$mode.log)"
  cmp -s r1$mode/render.tif r2$mode/render.tif && echo "  render.tif identical"
done
t=$(seconds t1.log taskset -c 0 "$H" --config train.yaml train --init "$model" --data "$views" -o t1 --backend cpu)
echo "train, 1 core: $t s"
t=$(seconds t2.log mpirun --allow-run-as-root -np 2 --bind-to core "$H" --config train.yaml train --init "$model" --data "$views" -o t2 --backend cpu)
echo "train, 2 ranks: $t s"
echo "epoch, seconds, loss, psnr (1 core) | seconds, loss, psnr (2 ranks)"
paste -d' ' <(cut -d, -f1-4 t1/log.csv) <(cut -d, -f2-4 t2/log.csv)
