#!/usr/bin/env bash
# `make bench-inference` (issue 8): decision latency of the learned policy (preprocessing + forward + decoding +
# quad_msgs/Bspline construction) in C++ at 1 and 2 threads and in Python, median and p99, at the default input
# size (config/train.yaml), on the same 200 depth frames rendered by the simulator core in the default world (a
# flight-like sequence at 2 m/s along the start-goal line of config/sim.yaml); and on the same frames the expert's
# cost per decision (map update + plan, fast_planner core). The policy is exported from a randomly initialised
# model of the default config: latency does not depend on the weights. Assumes the workspace is built and
# sourced. BENCH lines on stdout; progress on stderr. Work files: $QUAD_IL_BENCH_DIR (default build/bench/inference).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"
OUT=${QUAD_IL_BENCH_DIR:-$ROOT/build/bench/inference}
FRAMES=${QUAD_IL_BENCH_FRAMES:-200}
REPEAT=${QUAD_IL_BENCH_REPEAT:-2}
mkdir -p "$OUT"
bench=""
IFS=: read -r -a prefixes <<< "${CMAKE_PREFIX_PATH:-}"
for p in "${prefixes[@]}"; do
  if [ -n "$p" ] && [ -x "$p/lib/quad_bench/policy_bench" ]; then
    bench="$p/lib/quad_bench/policy_bench"
    break
  fi
done
if [ -z "$bench" ]; then
  echo "bench inference: policy_bench not found in CMAKE_PREFIX_PATH (build the workspace and source it)" >&2
  exit 1
fi
echo "[bench inference] random-init policy of the default model config -> $OUT/policy.ts" >&2
python -m quad_il.inference.random_policy --config config/train.yaml --out "$OUT/policy.ts" --seed 0
echo "[bench inference] rendering $FRAMES depth frames (config/sim.yaml, world seed 1)" >&2
rm -rf "$OUT/frames"
"$bench" frames --sim-config config/sim.yaml --seed 1 --count "$FRAMES" --out "$OUT/frames"
common=(--policy "$OUT/policy.ts" --fixture "$OUT/frames" --config config/policy.yaml --repeat "$REPEAT")
"$bench" time "${common[@]}" --threads 1 --name infer_cpp1
"$bench" time "${common[@]}" --threads 2 --name infer_cpp2
python -m quad_il.inference.bench "${common[@]}" --threads 1 --name infer_py
rc=0
"$bench" expert --planner-config config/planner.yaml --fixture "$OUT/frames" || rc=$?
if [ "$rc" = 3 ]; then
  echo "[bench inference] expert_decision_ms_median left out: policy_bench was built without fast_planner" >&2
elif [ "$rc" != 0 ]; then
  exit "$rc"
fi
