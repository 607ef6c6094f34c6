# Source this file (bash) to get a shell with the quad_il workspace: the venv's python first on PATH and the
# catkin devel space sourced. `make shell` opens such a shell.
# shellcheck shell=bash
QUAD_IL_ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
export QUAD_IL_ROOT
export PATH="$QUAD_IL_ROOT/.venv/bin:$PATH"
if [ -f "$QUAD_IL_ROOT/devel/setup.bash" ]; then
  # devel/setup.bash reads unset variables: it fails under `set -u`.
  case $- in *u*) _quad_il_had_u=1; set +u ;; *) _quad_il_had_u=0 ;; esac
  # shellcheck disable=SC1091
  source "$QUAD_IL_ROOT/devel/setup.bash"
  [ "$_quad_il_had_u" = 1 ] && set -u
  unset _quad_il_had_u
fi
# The ROS-free learning package is importable without the devel space too (tests, training_only/).
case ":${PYTHONPATH:-}:" in
  *":$QUAD_IL_ROOT/src/quad_il/src:"*) ;;
  *) export PYTHONPATH="$QUAD_IL_ROOT/src/quad_il/src${PYTHONPATH:+:$PYTHONPATH}" ;;
esac
