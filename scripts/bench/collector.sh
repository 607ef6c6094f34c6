#!/usr/bin/env bash
# `make bench-collector`: BENCH lines of cpp_data_collector and collect.launch (docs/cpp_data_collector.md,
# docs/collect.md). Assumes the workspace is built and sourced (scripts/bench.sh does both). Progress goes to stderr.
# 1. python -m quad_il.data.bench: per-record cost of DatasetWriter::Record on the caller's thread (synthetic
#    320x240 records at 100 Hz), and the shards-vs-npz trade-off (load speed, size on disk).
# 2. python -m quad_il.collection.bench: a real `roslaunch quad_il collect.launch` run in lockstep (2 episodes):
#    collection speed (sim seconds per wall second, records per wall second) and the largest depth-odometry
#    stamp gap over its records.
set -euo pipefail
python -m quad_il.data.bench
python -m quad_il.collection.bench
