"""`--help` of the harness tools (src/quad_bench/tools): exit 0, and every option is listed with its default
or as required, so a user never has to read the source to know what a run did."""

from __future__ import annotations

import re
import subprocess

import pytest

from quad_il.tools.binaries import BinaryNotFound, find_binary

TOOLS = ["tracker_eval", "planner_bench", "policy_bench", "expert_clearance_flights", "config_check"]


def _tool(name: str):
    try:
        return find_binary("quad_bench", name)
    except BinaryNotFound as e:
        pytest.skip(str(e))


@pytest.mark.parametrize("name", TOOLS)
def test_help_lists_every_option_with_its_default(name: str) -> None:
    out = subprocess.run([str(_tool(name)), "--help"], capture_output=True, text=True, timeout=30)
    assert out.returncode == 0, f"{name} --help exited {out.returncode}: {out.stderr}"
    assert out.stdout.startswith("usage:"), out.stdout
    # Each option described on a line of its own says its default or that it is required.
    described = [ln for ln in out.stdout.splitlines() if re.match(r"^\s+--[a-z]", ln)]
    for line in described:
        assert re.search(r"\((default: [^)]+|required)\)", line), f"{name}: no default in '{line.strip()}'"
    if name != "config_check":
        assert described, f"{name} --help describes no option"


def test_usage_error_exits_2_with_the_usage() -> None:
    out = subprocess.run(
        [str(_tool("planner_bench")), "--no-such-option"], capture_output=True, text=True, timeout=30
    )
    assert out.returncode == 2
    assert "unknown argument --no-such-option" in out.stderr
    assert "--min-replans N" in out.stderr
