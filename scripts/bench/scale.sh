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

# Collection: parallel collection workers (collect_rps_1worker, collect_rps_2workers). Not written yet: the
# lead replaces this function's body with the measurement.
bench_collection() {
  echo "bench-scale: collect_rps_1worker, collect_rps_2workers: not measured yet (the collection part of" \
    "scripts/bench/scale.sh is not written)" >&2
  return 3
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
