"""fast_planner's benchmark plumbing and configuration, checked without building or flying anything.

- scripts/bench/planner.names lists exactly the BENCH names of issue 5, and planner_bench prints each of them;
- scripts/bench/planner.sh passes SEEDS / WORLDS / DENSITY (as `make bench-planner SEEDS=...` sets them) on to
  the benchmark binary (run against a stand-in binary that echoes its arguments);
- every key of config/planner.yaml is documented in docs/fast_planner.md, and the launch file loads that
  config.
"""

from __future__ import annotations

import os
import stat
import subprocess
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]

ISSUE_NAMES = [
    "planner_frontend_ms_median",
    "planner_frontend_ms_p90",
    "planner_frontend_ms_p99",
    "planner_opt_ms_median",
    "planner_opt_ms_p90",
    "planner_opt_ms_p99",
    "planner_total_ms_median",
    "planner_total_ms_p90",
    "planner_total_ms_p99",
    "planner_map_update_ms_median",
    "planner_goals_reached",
    "planner_goals_total",
    "planner_collisions",
    "planner_min_clearance_m",
    "planner_mean_speed_mps",
    "planner_path_ratio",
]


def test_names_file_lists_exactly_the_issue_names() -> None:
    names = (ROOT / "scripts/bench/planner.names").read_text().split()
    assert names == ISSUE_NAMES


def test_the_benchmark_source_prints_every_name() -> None:
    src = (ROOT / "src/quad_bench/tools/planner_bench.cpp").read_text()
    for name in ISSUE_NAMES:
        stem = name.removeprefix("planner_")
        # Timing names are built as "planner_" + {frontend, opt, total} + "_ms_" + statistic.
        parts = stem.split("_ms_")
        if len(parts) == 2 and parts[0] in ("frontend", "opt", "total"):
            assert f'"{parts[0]}"' in src and f'"_ms_{parts[1]}"' in src, name
        else:
            assert f'"{name}"' in src, name


@pytest.fixture()
def echo_binary(tmp_path: Path) -> Path:
    """A stand-in for planner_bench that prints its arguments, one per line."""
    script = tmp_path / "planner_bench"
    script.write_text('#!/usr/bin/env bash\nfor a in "$@"; do echo "ARG $a"; done\n')
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    return script


def run_bench_script(binary: Path, **env_vars: str) -> list[str]:
    env = {k: v for k, v in os.environ.items() if k not in ("SEEDS", "WORLDS", "DENSITY")}
    env.update(env_vars)
    env["PLANNER_BENCH"] = str(binary)
    out = subprocess.run(
        ["bash", str(ROOT / "scripts/bench/planner.sh")], env=env, capture_output=True, text=True, check=True
    )
    return [line.removeprefix("ARG ") for line in out.stdout.splitlines() if line.startswith("ARG ")]


def value_after(args: list[str], flag: str) -> str | None:
    return args[args.index(flag) + 1] if flag in args else None


def test_bench_script_passes_seeds_density_and_worlds_on(echo_binary: Path) -> None:
    args = run_bench_script(echo_binary, SEEDS="4,8,15", DENSITY="18.5", WORLDS="3")
    assert value_after(args, "--seeds") == "4,8,15"
    assert value_after(args, "--density") == "18.5"
    assert value_after(args, "--worlds") == "3"
    assert value_after(args, "--planner-config") == "config/planner.yaml"
    assert value_after(args, "--min-replans") == "200"


def test_bench_script_defaults_to_twenty_worlds_at_the_configured_density(echo_binary: Path) -> None:
    args = run_bench_script(echo_binary)
    assert value_after(args, "--worlds") == "20"
    assert "--seeds" not in args
    assert "--density" not in args


def test_bench_script_fails_clearly_without_the_binary(tmp_path: Path) -> None:
    env = dict(os.environ)
    env["PLANNER_BENCH"] = str(tmp_path / "missing" / "planner_bench")
    script = str(ROOT / "scripts/bench/planner.sh")
    out = subprocess.run(["bash", script], env=env, capture_output=True, text=True)
    assert out.returncode == 1
    assert f"planner_bench not found at {tmp_path / 'missing' / 'planner_bench'}" in out.stderr
    assert "BENCH" not in out.stdout


def leaf_keys(node: object, prefix: str = "") -> list[str]:
    if isinstance(node, dict):
        keys: list[str] = []
        for k, v in node.items():
            keys.extend(leaf_keys(v, f"{prefix}.{k}" if prefix else str(k)))
        return keys
    return [prefix]


def test_every_config_key_is_documented() -> None:
    config = yaml.safe_load((ROOT / "config/planner.yaml").read_text())
    doc = (ROOT / "docs/fast_planner.md").read_text()
    keys = leaf_keys(config)
    assert len(keys) > 40
    missing = [k for k in keys if f"`{k}`" not in doc]
    assert not missing, f"undocumented keys in docs/fast_planner.md: {missing}"


def test_launch_file_runs_the_node_with_the_planner_config() -> None:
    launch = (ROOT / "launch/planner.launch").read_text()
    assert 'type="fast_planner_node"' in launch
    assert "config/planner.yaml" in launch
