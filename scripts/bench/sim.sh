#!/usr/bin/env bash
# Benchmark of quad_sim (issue 3): depth render time per frame and the real-time factor of the whole simulator
# loop (1 kHz dynamics, 200 Hz odometry, 30 Hz depth, as fast as possible, no ROS) in the default world of
# config/sim.yaml, at 160x120, 320x240 and 640x480. Assumes the workspace is built and sourced.
# Prints `BENCH <name> <value> <unit>` on stdout; progress on stderr.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
bench=""
IFS=: read -r -a prefixes <<< "${CMAKE_PREFIX_PATH:-}"
for p in "${prefixes[@]}"; do
  if [ -n "$p" ] && [ -x "$p/lib/quad_sim/quad_sim_bench" ]; then
    bench="$p/lib/quad_sim/quad_sim_bench"
    break
  fi
done
if [ -z "$bench" ]; then
  echo "bench sim: quad_sim_bench not found in CMAKE_PREFIX_PATH (build the workspace and source it)" >&2
  exit 1
fi
for res in 160x120 320x240 640x480; do
  echo "[bench sim] $res: 300 depth frames, 30 s of simulation" >&2
  "$bench" --config "$ROOT/config/sim.yaml" --width "${res%x*}" --height "${res#*x}" --frames 300 --sim-seconds 30
done
