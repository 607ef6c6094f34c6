#!/usr/bin/env bash
# `make demo`: the main job end to end on the default configuration. It grows with the pipeline; it runs the
# stages that exist and says which do not exist yet.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh
OUT=${OUT:-$ROOT/results/demo}
mkdir -p "$OUT"
PORT=${ROS_PORT:-$(python -c 'import socket; s=socket.socket(); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')}
export ROS_MASTER_URI=http://127.0.0.1:$PORT
export ROS_HOME=$OUT/ros_home
pids=()
cleanup() { for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done; wait 2>/dev/null || true; }
trap cleanup EXIT

echo "[demo] stage 1/1: message interfaces (private ROS master on port $PORT)"
roscore -p "$PORT" > "$OUT/roscore.log" 2>&1 & pids+=($!)
until rostopic list >/dev/null 2>&1; do sleep 0.2; done
rosrun quad_il bspline_test_publisher __name:=demo_bspline_pub > "$OUT/publisher.log" 2>&1 & pids+=($!)
timeout 20 rostopic echo -n 1 /demo_bspline_pub/bspline > "$OUT/bspline.txt"
echo "[demo] a Bspline published from C++ and received by Python: $OUT/bspline.txt"
echo "[demo] md5 quad_msgs/Bspline = $(rosmsg md5 quad_msgs/Bspline) (Fast-Planner: b352d4f7278a546180de67cbe6793e49)"
echo "[demo] not built yet: simulator (issue 3), tracker (4), expert planner (5), collection (6), training (7),"
echo "[demo]                closed-loop evaluation (8), interactive imitation learning (9)."
