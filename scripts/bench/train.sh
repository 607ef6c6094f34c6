#!/usr/bin/env bash
# `make bench-train` (issue 7): training samples/s at the default input size, data-loader samples/s and peak
# memory, on a synthetic dataset at camera resolution in the collector's .npz layout (no collected data needed).
# BENCH lines on stdout; progress on stderr. Extra arguments go to `python -m quad_il.learning.bench`
# (e.g. --set model.input_height=128 --set model.input_width=128).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh
exec python -m quad_il.learning.bench --config config/train.yaml "$@"
