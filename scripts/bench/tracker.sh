#!/usr/bin/env bash
# kr_tracker benchmark (`make bench-tracker`): closed-loop checks against the simulator core in-process with the
# repository's configs, and the controller's update time. Prints the BENCH lines of issue 4 on stdout; progress,
# per-axis numbers and the location of the step-response plot go to stderr. Outputs (CSV + PNG) in
# ${TRACKER_BENCH_OUT:-build/bench/tracker}. Assumes the workspace is built and sourced (scripts/env.sh).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"
OUT=${TRACKER_BENCH_OUT:-$ROOT/build/bench/tracker}
mkdir -p "$OUT"

# tracker_eval from the first devel space on CMAKE_PREFIX_PATH that has it (the main one, or a private one).
EVAL=${TRACKER_EVAL:-}
if [ -z "$EVAL" ]; then
  IFS=: read -r -a prefixes <<< "${CMAKE_PREFIX_PATH:-}"
  for p in "${prefixes[@]}" "$ROOT/devel"; do
    if [ -x "$p/lib/quad_bench/tracker_eval" ]; then EVAL="$p/lib/quad_bench/tracker_eval"; break; fi
  done
fi
if [ -z "$EVAL" ]; then
  echo "bench tracker: tracker_eval not found (build quad_bench first)" >&2
  exit 1
fi
CONFIGS=(--tracker-config config/tracker.yaml --vehicle-config config/vehicle.yaml --sim-config config/sim.yaml)

# `result <name> <value> <unit>` lines of tracker_eval -> "name value" pairs in this associative array.
declare -A R
collect() {
  local line name value
  while read -r line; do
    case $line in
      result\ *) read -r _ name value _ <<< "$line"; R[$name]=$value ;;
    esac
  done
}

echo "[bench tracker] step response: hover at (0, 0, 1), step of (3, 3, 3) m" >&2
collect < <("$EVAL" step "${CONFIGS[@]}" --csv "$OUT/step_response.csv")
title=$(printf 'Step (3, 3, 3) m: overshoot %.2f %%, rise %.2f s, settling (2 %%) %.2f s, sse %.4f m' \
  "${R[step_overshoot_pct]}" "${R[step_rise_s]}" "${R[step_settle_s]}" "${R[step_sse_m]}")
python "$ROOT/src/kr_tracker/scripts/plot_step_response.py" "$OUT/step_response.csv" "$OUT/step_response.png" \
  --title "$title"
echo "[bench tracker] step-response plot: $OUT/step_response.png" >&2

echo "[bench tracker] figure eight at 2 m/s peak through the B-spline tracker" >&2
collect < <("$EVAL" fig8 "${CONFIGS[@]}" --csv "$OUT/fig8.csv")

echo "[bench tracker] controller update time" >&2
collect < <("$EVAL" update-time "${CONFIGS[@]}")

for k in step_rejected_commands fig8_rejected_commands; do
  if [ "${R[$k]}" != 0 ]; then echo "[bench tracker] WARNING: $k = ${R[$k]}" >&2; fi
done
echo "BENCH tracker_step_overshoot_pct ${R[step_overshoot_pct]} %"
echo "BENCH tracker_step_rise_s ${R[step_rise_s]} s"
echo "BENCH tracker_step_settle_s ${R[step_settle_s]} s"
echo "BENCH tracker_step_sse_m ${R[step_sse_m]} m"
echo "BENCH tracker_fig8_rms_m ${R[fig8_rms_m]} m"
echo "BENCH tracker_fig8_max_m ${R[fig8_max_m]} m"
echo "BENCH tracker_update_us ${R[update_us]} us"
