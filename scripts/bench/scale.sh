#!/usr/bin/env bash
# `make bench-scale` (issue 9, Scale): collection records/s with 1 and 2 workers, training samples/s with 1
# and 2 DDP processes. One function per part; BENCH lines on stdout, progress on stderr (docs/scaling.md).
#   bash scripts/bench/scale.sh [training] [collection]     (default: every part)
# Exit status: 0 when every part measured; 1 when a part failed; 3 when a part is not measured yet (it says
# so on stderr and prints no BENCH line, so bench_check also names its missing names).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh

# Training: the default configuration on a synthetic dataset, 1 process x 2 threads, then 2 DDP processes
# (torchrun, gloo) x 1 thread, same data and global batch; about a minute each. Also prints both runs'
# validation losses (plain lines). Extra options: SCALE_TRAIN_ARGS="--epochs 4 --set dist.sync_batchnorm=false".
bench_training() {
  # shellcheck disable=SC2086
  python -m quad_il.learning.scale_bench ${SCALE_TRAIN_ARGS:-}
}

# Collection: `python -m quad_il.collection.parallel` with 1 and then 2 workers on the same world seeds and
# episode count (lockstep collect.launch workers, each on its own ROS master port), records per wall second of
# the whole run (start-up and finalisation included). SCALE_COLLECT_SEEDS / SCALE_COLLECT_EPISODES change them.
bench_collection() {
  local work seeds episodes n rps
  work=$(mktemp -d "${TMPDIR:-/tmp}/bench_scale_collect.XXXXXX")
  seeds=${SCALE_COLLECT_SEEDS:-1-6}
  episodes=${SCALE_COLLECT_EPISODES:-6}
  for n in 1 2; do
    echo "[bench scale] collection with $n worker(s): seeds $seeds, $episodes episodes -> $work/w$n" >&2
    python -m quad_il.collection.parallel --backend ros --workers "$n" --seeds "$seeds" --episodes "$episodes" \
      --out "$work/w$n" --timeout-s 1800 >&2 || { rm -rf "$work"; return 1; }
    rps=$(python -c 'import sys, yaml; print(yaml.safe_load(open(sys.argv[1]))["records_per_s"])' \
      "$work/w$n/collection.yaml")
    if [ "$n" = 1 ]; then echo "BENCH collect_rps_1worker $rps records/s"; else echo "BENCH collect_rps_2workers $rps records/s"; fi
  done
  rm -rf "$work"
}

parts=("$@")
[ ${#parts[@]} -eq 0 ] && parts=(training collection)
status=0
for part in "${parts[@]}"; do
  if ! declare -F "bench_$part" >/dev/null; then
    echo "bench-scale: unknown part '$part' (parts: training collection)" >&2
    exit 2
  fi
  rc=0
  "bench_$part" || rc=$?
  if [ "$rc" -eq 3 ]; then
    [ "$status" -eq 0 ] && status=3
  elif [ "$rc" -ne 0 ]; then
    echo "bench-scale: part '$part' failed (exit $rc)" >&2
    status=1
  fi
done
exit "$status"
