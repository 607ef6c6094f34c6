#!/usr/bin/env bash
# Idempotent set-up of a quad_il workspace on Debian 12:
#   1. Debian packages (ROS 1, Bullet, NLopt, ...) from scripts/apt-packages.txt, only the missing ones;
#   2. .venv from Debian's /usr/bin/python3 with system site packages (so rospy/cv2 come from Debian);
#   3. pinned pip requirements (requirements.txt, constrained by constraints.txt), skipped when unchanged;
#   4. the quad_il Python package (src/quad_il) installed into .venv as editable, so training_only/ and the
#      other scripts import it without touching sys.path; skipped when .venv already imports it from here.
# When everything is in place this takes about a second. Extra packages for experiments:
#   QUAD_IL_EXTRA_APT="pkg ..."  QUAD_IL_EXTRA_PIP="req ..."
# QUAD_IL_SETUP_STEPS (default "apt venv pip pkg") selects steps.
set -euo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
STEPS=${QUAD_IL_SETUP_STEPS:-apt venv pip pkg}
say() { echo "[setup] $*"; }
die() { echo "[setup] ERROR: $*" >&2; exit 1; }

step_apt() {
  local wanted=() missing=() unknown=() p
  while read -r p; do
    p=${p%%#*}; p=${p//[[:space:]]/}
    [ -n "$p" ] && wanted+=("$p")
  done < scripts/apt-packages.txt
  for p in ${QUAD_IL_EXTRA_APT:-}; do wanted+=("$p"); done
  for p in "${wanted[@]}"; do
    if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
      missing+=("$p")
    fi
  done
  if [ ${#missing[@]} -eq 0 ]; then
    say "apt: all ${#wanted[@]} Debian packages present"
    return
  fi
  say "apt: installing ${#missing[@]} missing package(s): ${missing[*]}"
  local SUDO=""
  if [ "$(id -u)" -ne 0 ]; then
    command -v sudo >/dev/null || die "apt: need root (or sudo) to install: ${missing[*]}"
    SUDO=sudo
  fi
  # Package lists are fetched once; an empty list cache is the fresh-machine case.
  if [ -z "$(ls -A /var/lib/apt/lists 2>/dev/null | grep -v -e lock -e partial)" ]; then
    $SUDO apt-get update -qq || die "apt: 'apt-get update' failed (no access to Debian's archive?)"
  fi
  for p in "${missing[@]}"; do
    apt-cache show "$p" >/dev/null 2>&1 || unknown+=("$p")
  done
  if [ ${#unknown[@]} -gt 0 ]; then
    $SUDO apt-get update -qq || true
    local still=()
    for p in "${unknown[@]}"; do apt-cache show "$p" >/dev/null 2>&1 || still+=("$p"); done
    [ ${#still[@]} -eq 0 ] || die "apt: package(s) not found in Debian's archive: ${still[*]}"
  fi
  local log
  log=$(mktemp)
  if ! DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends "${missing[@]}" >"$log" 2>&1; then
    tail -n 20 "$log" >&2
    die "apt: 'apt-get install' failed for: ${missing[*]} (full log: $log)"
  fi
  rm -f "$log"
}

step_venv() {
  if [ -x .venv/bin/python ] && .venv/bin/python -c 'import rospy' 2>/dev/null; then
    say "venv: .venv present"
    return
  fi
  [ -x /usr/bin/python3 ] || die "venv: /usr/bin/python3 (Debian's python3) not found"
  say "venv: creating .venv from /usr/bin/python3 with system site packages"
  rm -rf .venv
  /usr/bin/python3 -m venv --system-site-packages .venv || die "venv: 'python3 -m venv' failed (is python3-venv installed?)"
  .venv/bin/python -c 'import rospy' || die "venv: rospy not importable from .venv (is python3-rospy installed?)"
}

step_pip() {
  local stamp=.venv/.quad_il_requirements.sha256 want
  want=$( { cat requirements.txt constraints.txt; echo "${QUAD_IL_EXTRA_PIP:-}"; } | sha256sum | cut -d' ' -f1)
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ]; then
    say "pip: requirements unchanged"
    return
  fi
  say "pip: installing requirements.txt ${QUAD_IL_EXTRA_PIP:-}"
  local log
  log=$(mktemp)
  # shellcheck disable=SC2086
  if ! .venv/bin/pip install --disable-pip-version-check -q -c constraints.txt -r requirements.txt \
        ${QUAD_IL_EXTRA_PIP:-} >"$log" 2>&1; then
    tail -n 20 "$log" >&2
    local what
    what=$(grep -oE "(No matching distribution found for|Could not find a version that satisfies the requirement) [^ ]+" "$log" | head -n 3 | awk '{print $NF}' | tr '\n' ' ')
    die "pip: install failed${what:+ for: $what}(full log: $log)"
  fi
  rm -f "$log"
  .venv/bin/python -c 'import numpy, cv2, torch; assert numpy.__version__.startswith("1."), numpy.__version__' \
    || die "pip: the venv is inconsistent after install (numpy must stay 1.x for Debian's cv2)"
  echo "$want" > "$stamp"
}

step_pkg() {
  local src="$ROOT/src/quad_il/src" stamp=.venv/.quad_il_editable.sha256 want found
  [ -x .venv/bin/python ] || die "pkg: .venv/bin/python missing (run the venv step first)"
  want=$( { cat src/quad_il/setup.py src/quad_il/package.xml; echo "$src"; } | sha256sum | cut -d' ' -f1)
  # -I: ignore PYTHONPATH (scripts/env.sh and catkin's devel space put the source tree there), so this asks
  # what the venv alone imports.
  found=$(.venv/bin/python -I -c 'import quad_il; print(quad_il.__file__)' 2>/dev/null || true)
  if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && [ "$found" = "$src/quad_il/__init__.py" ]; then
    say "pkg: quad_il installed (editable, $src)"
    return
  fi
  say "pkg: installing quad_il into .venv (editable, $src)"
  local log
  log=$(mktemp)
  # catkin also runs src/quad_il/setup.py (catkin_python_setup, for the devel space); both use the one file.
  # It imports catkin_pkg (Debian's, a system site package): hence no build isolation. --use-pep517: pip 23's
  # legacy `setup.py develop` path would build in isolation anyway.
  if ! .venv/bin/pip install --disable-pip-version-check -q --no-deps --no-build-isolation --use-pep517 \
        -e src/quad_il >"$log" 2>&1; then
    tail -n 20 "$log" >&2
    die "pkg: 'pip install -e src/quad_il' failed (full log: $log)"
  fi
  rm -f "$log"
  found=$(.venv/bin/python -I -c 'import quad_il; print(quad_il.__file__)' 2>/dev/null || true)
  [ "$found" = "$src/quad_il/__init__.py" ] \
    || die "pkg: after the install .venv imports quad_il from '${found:-nowhere}', not $src/quad_il"
  echo "$want" > "$stamp"
}

for s in $STEPS; do
  case "$s" in
    apt) step_apt ;;
    venv) step_venv ;;
    pip) step_pip ;;
    pkg) step_pkg ;;
    *) die "unknown step '$s' in QUAD_IL_SETUP_STEPS (known: apt venv pip pkg)" ;;
  esac
done
