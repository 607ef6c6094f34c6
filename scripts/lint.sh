#!/usr/bin/env bash
# Formatting and lint: ruff (Python) and clang-format (C++), check only. `make format` applies both.
# `check` also fails on an import cycle between the quad_il Python subpackages (quad_il/tools/import_cycles.py).
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
mode=${1:-check}
mapfile -t cxx < <(git ls-files -co --exclude-standard -- 'src/*.cpp' 'src/*.h' 'src/*.hpp' | sort -u)
py_dirs=()
for d in src tests training_only; do [ -d "$d" ] && py_dirs+=("$d"); done
if [ "$mode" = fix ]; then
  .venv/bin/ruff format "${py_dirs[@]}"
  .venv/bin/ruff check --fix "${py_dirs[@]}"
  [ ${#cxx[@]} -eq 0 ] || clang-format -i "${cxx[@]}"
else
  .venv/bin/ruff check "${py_dirs[@]}"
  .venv/bin/ruff format --check "${py_dirs[@]}"
  [ ${#cxx[@]} -eq 0 ] || clang-format --dry-run --Werror "${cxx[@]}"
  # Standard library only: runs without the devel space or an installed quad_il.
  .venv/bin/python src/quad_il/src/quad_il/tools/import_cycles.py
fi
