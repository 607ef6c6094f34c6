#!/usr/bin/env bash
# Idempotent set-up + catkin build of the workspace with the venv's interpreter (so rospy nodes run with torch).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
bash scripts/setup.sh
# Without this directory the first `catkin_make run_tests` caches an empty PYTHONPATH (see PLATFORM.md).
mkdir -p devel/lib/python3/dist-packages
echo "[build] catkin_make (Release, python: .venv/bin/python)"
catkin_make -j"${QUAD_IL_JOBS:-2}" \
  -DPYTHON_EXECUTABLE="$ROOT/.venv/bin/python" \
  -DCMAKE_BUILD_TYPE=Release \
  -DCMAKE_EXPORT_COMPILE_COMMANDS=ON \
  "$@" > build.log 2>&1 || { tail -n 60 build.log >&2; echo "[build] ERROR: catkin_make failed (full log: $ROOT/build.log)" >&2; exit 1; }
grep -E "warning:" build.log | sort -u | head -n 20 || true
echo "[build] ok"
