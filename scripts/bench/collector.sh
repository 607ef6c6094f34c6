#!/usr/bin/env bash
# `make bench-collector`: BENCH lines of cpp_data_collector (docs/cpp_data_collector.md, "Benchmarks").
# Assumes the workspace is built and sourced (scripts/bench.sh does both). Progress goes to stderr.
# Measured here: the per-record cost of DatasetWriter::Record on the caller's thread, and the shards-vs-npz
# trade-off (load speed, size on disk). The lockstep collection numbers (collector_rtf, collector_records_per_s,
# collector_max_stamp_gap_ms) need the simulator, planner and collect.launch, which do not exist yet.
set -euo pipefail
exec python -m quad_il.data.bench "$@"
