#!/usr/bin/env bash
# fast_planner benchmark (`make bench-planner`): ROS-free closed-loop flights of the expert in the simulator core
# (quad_sim + kr_tracker's controller and B-spline tracker + the planner, in-process and deterministic).
#   Timing: flights between a fixed list of start/goal pairs in a fixed seeded world (PLANNER_TIMING_SEED, default 1)
#           until at least PLANNER_MIN_REPLANS (default 200) plans; per-plan front-end / optimisation / total time
#           and per-depth-frame map update time, as the planning thread's CPU time.
#   Flight quality: one 30 m start/goal pair per seeded world.
# Arguments, as environment variables (make passes its command-line variables on):
#   SEEDS    comma-separated world seeds, e.g. SEEDS=1,2,3 (default: 1..WORLDS)
#   WORLDS   number of worlds when SEEDS is not given (default 20)
#   DENSITY  boxes per 100 m^2 (default: config/sim.yaml's generator, 200 boxes in 40 x 40 m = 12.5)
# Prints the BENCH lines of issue 5 on stdout, per-flight progress on stderr. Assumes the workspace is built and
# sourced (scripts/env.sh).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"

# planner_bench from the first devel space on CMAKE_PREFIX_PATH that has it (the main one, or a private one).
BENCH_BIN=${PLANNER_BENCH:-}
if [ -z "$BENCH_BIN" ]; then
  IFS=: read -r -a prefixes <<< "${CMAKE_PREFIX_PATH:-}"
  for p in "${prefixes[@]}" "$ROOT/devel"; do
    if [ -x "$p/lib/quad_bench/planner_bench" ]; then BENCH_BIN="$p/lib/quad_bench/planner_bench"; break; fi
  done
fi
if [ -z "$BENCH_BIN" ] || [ ! -x "$BENCH_BIN" ]; then
  echo "bench planner: planner_bench not found${BENCH_BIN:+ at $BENCH_BIN} (build quad_bench first)" >&2
  exit 1
fi

args=(--planner-config config/planner.yaml --sim-config config/sim.yaml --tracker-config config/tracker.yaml
      --worlds "${WORLDS:-20}" --timing-seed "${PLANNER_TIMING_SEED:-1}" --min-replans "${PLANNER_MIN_REPLANS:-200}")
[ -n "${SEEDS:-}" ] && args+=(--seeds "$SEEDS")
[ -n "${DENSITY:-}" ] && args+=(--density "$DENSITY")
echo "[bench planner] $BENCH_BIN ${args[*]}" >&2
"$BENCH_BIN" "${args[@]}"
