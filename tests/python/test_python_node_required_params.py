"""The Python nodes have no parameter defaults (issue 31): the episode manager and the interactive collector
stop at start with exit status 2 and a message naming the missing parameter and the file that sets it.

Starts each node's script against a private ROS master (rosmaster --core on a free port). About 8 s.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

rosgraph = pytest.importorskip("rosgraph")

ROOT = Path(__file__).resolve().parents[2]
NODES = ROOT / "src" / "quad_il" / "nodes"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def master_env() -> Iterator[dict[str, str]]:
    port = free_port()
    env = dict(os.environ, ROS_MASTER_URI=f"http://127.0.0.1:{port}/")
    proc = subprocess.Popen(
        ["rosmaster", "--core", "-p", str(port)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    master = rosgraph.Master("/required_params_probe", master_uri=env["ROS_MASTER_URI"])
    deadline = time.monotonic() + 20.0
    while True:
        try:
            master.getPid()
            break
        except OSError:
            if time.monotonic() > deadline:
                proc.kill()
                pytest.fail("rosmaster did not come up within 20 s")
            time.sleep(0.1)
    yield env
    proc.terminate()
    proc.wait(timeout=10)


def run_node(script: str, env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(NODES / script), *args], env=env, capture_output=True, text=True, timeout=60
    )


def test_the_episode_manager_names_a_missing_parameter(master_env: dict[str, str], tmp_path: Path) -> None:
    given = [
        f"_config:={ROOT / 'config' / 'collect.yaml'}",
        f"_output_dir:={tmp_path}",
        "_lockstep:=false",
        "_frame_ack_consumer:=episode_manager",
        "_planner_consumer:=fast_planner",
        "_odom_period_s:=0.005",
    ]
    proc = run_node("episode_manager.py", master_env, "__name:=em_probe", *given)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert (
        "missing parameter '~tracker_node' (resolved: /em_probe/tracker_node; "
        "set it in launch/collect.launch or launch/il_sim.launch)"
    ) in proc.stderr


def test_the_collector_names_a_missing_parameter(master_env: dict[str, str], tmp_path: Path) -> None:
    proc = run_node("imitation_collector.py", master_env, "__name:=ic_probe", f"_output_dir:={tmp_path}")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "missing parameter '~round_config' (resolved: /ic_probe/round_config" in proc.stdout + proc.stderr
