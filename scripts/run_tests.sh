#!/usr/bin/env bash
# The whole test suite: lint, C++ unit tests (gtest, ROS-free), rostest integration tests, Python tests (pytest).
# Prints one summary line `N passed, N failed, N skipped` and exits non-zero on any failure.
# Assumes `make build` ran (the Makefile's `test` target does that first).
set -uo pipefail
ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
cd "$ROOT"
# shellcheck disable=SC1091
source scripts/env.sh
RESULTS="$ROOT/build/test_results"
rm -rf "$RESULTS"
mkdir -p "$RESULTS/pytest" "$RESULTS/lint"
status=0

echo "[test] lint (ruff, clang-format)"
if bash scripts/lint.sh > build/lint.log 2>&1; then
  lint_case='<testcase classname="lint" name="ruff_and_clang_format"/>'
else
  cat build/lint.log
  lint_case='<testcase classname="lint" name="ruff_and_clang_format"><failure message="lint failed: see build/lint.log"/></testcase>'
fi
echo "<testsuite name=\"lint\">$lint_case</testsuite>" > "$RESULTS/lint/lint.xml"

echo "[test] C++ unit tests and rostests (catkin_make run_tests)"
# ROS_HOME keeps rostest logs inside the workspace; rostest picks its own master port.
export ROS_HOME="$ROOT/build/ros_home"
if ! catkin_make -j"${QUAD_IL_JOBS:-2}" run_tests > build/run_tests.log 2>&1; then
  tail -n 40 build/run_tests.log
  echo "[test] ERROR: catkin_make run_tests failed to build or run (log: build/run_tests.log)"
  status=1
fi

echo "[test] Python tests (pytest)"
python -m pytest -q -p no:cacheprovider --junitxml="$RESULTS/pytest/pytest.xml" tests/python "$@" \
  > build/pytest.log 2>&1
pytest_rc=$?
tail -n 15 build/pytest.log
# 5 = no tests collected: counted by the summary below, not a crash.
if [ "$pytest_rc" -ne 0 ] && [ "$pytest_rc" -ne 1 ] && [ "$pytest_rc" -ne 5 ]; then
  echo "[test] ERROR: pytest exited $pytest_rc (log: build/pytest.log)"
  status=1
fi

echo "[test] summary (JUnit results in build/test_results)"
python -m quad_il.tools.test_summary "$RESULTS" || status=1
exit $status
