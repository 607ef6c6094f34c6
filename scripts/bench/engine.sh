#!/usr/bin/env bash
# `make bench-engine` (issue 32, "Benchmarks"; docs/engine.md, "Benchmarks"): the rollout engine against the ROS
# path, in one run on the same episode keys: collect.launch (lockstep, 1 worker, depth-mapping expert) as the
# baseline, the engine's depth-mapping and privileged experts in one process, 8 policy episodes with one batched
# LibTorch forward pass per round of decisions, engine-vs-ROS parity of the records, and the Ray backend with 1
# and 2 actors. BENCH lines and the machine's load (`load ...` lines) on stdout, progress on stderr.
# Arguments, as environment variables:
#   ENGINE_BENCH_SEEDS     world seeds of the collection parts (default 1-6)
#   ENGINE_BENCH_EPISODES  episodes of the collection parts (default 6; about 5-8 minutes in all here)
#   ENGINE_BENCH_PARTS     comma-separated parts (default: ros,expert,privileged,policy,ray)
# Assumes the workspace is built (scripts/bench.sh builds and sources it; sourced again here to run alone).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh
args=(--seeds "${ENGINE_BENCH_SEEDS:-1-6}" --episodes "${ENGINE_BENCH_EPISODES:-6}")
[ -n "${ENGINE_BENCH_PARTS:-}" ] && args+=(--parts "$ENGINE_BENCH_PARTS")
echo "[bench engine] python -m quad_il.engine_bench ${args[*]}" >&2
python -m quad_il.engine_bench "${args[@]}"
