#!/usr/bin/env bash
# `make bench-<component>`: runs scripts/bench/<component>.sh and checks its output against the BENCH
# convention (`BENCH <name> <value> <unit>`, nothing else on lines starting with BENCH) and the exact names the
# component's issue asks for (scripts/bench/<component>.names, one per line).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
component=${1:?usage: bench.sh <component>}
script="scripts/bench/$component.sh"
if [ ! -f "$script" ]; then
  shopt -s nullglob
  avail=""
  for f in scripts/bench/*.sh; do avail+="$(basename "$f" .sh) "; done
  echo "bench: no benchmark for component '$component' (available: ${avail:-none yet})" >&2
  exit 2
fi
# shellcheck disable=SC1091
source scripts/env.sh
expect=()
if [ -f "scripts/bench/$component.names" ]; then
  while read -r n; do [ -n "$n" ] && expect+=(--expect "$n"); done < "scripts/bench/$component.names"
fi
bash "$script" | python -m quad_il.tools.bench_check "${expect[@]}"
