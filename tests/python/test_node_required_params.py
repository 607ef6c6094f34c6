"""The expert's and the tracker's nodes have no parameter defaults in their code (issue 31): a missing
parameter stops the node at start with exit status 1 and a message naming it; so does one of the wrong type.

Each case starts the node binary against a private ROS master (rosmaster --core on a free port) with some
parameters left out. About 10 s in all.
"""

from __future__ import annotations

import os
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

rosgraph = pytest.importorskip("rosgraph")

from quad_il.tools.binaries import BinaryNotFound, find_binary  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
PLANNER_YAML = str(ROOT / "config" / "planner.yaml")
START_TIMEOUT_S = 60.0


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def master() -> Iterator[str]:
    uri = f"http://127.0.0.1:{free_port()}/"
    env = dict(os.environ, ROS_MASTER_URI=uri)
    port = uri.rsplit(":", 1)[1].strip("/")
    proc = subprocess.Popen(
        ["rosmaster", "--core", "-p", port], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    try:
        m = rosgraph.Master("/test_node_required_params", master_uri=uri)
        deadline = time.monotonic() + 30.0
        while not m.is_online():
            assert proc.poll() is None, "rosmaster exited at start"
            assert time.monotonic() < deadline, "rosmaster did not come up"
            time.sleep(0.1)
        yield uri
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def run_node(uri: str, package: str, binary: str, name: str, params: dict[str, Any]) -> tuple[int, str]:
    """Sets exactly `params` under /<name>/ (the namespace cleared first), runs the node: (exit, output)."""
    try:
        exe = find_binary(package, binary)
    except BinaryNotFound as exc:
        pytest.skip(str(exc))
    m = rosgraph.Master("/test_node_required_params", master_uri=uri)
    if m.hasParam(f"/{name}"):
        m.deleteParam(f"/{name}")
    for key, value in params.items():
        m.setParam(f"/{name}/{key}", value)
    env = dict(os.environ, ROS_MASTER_URI=uri)
    proc = subprocess.run(
        [str(exe), f"__name:={name}"],
        env=env,
        capture_output=True,
        text=True,
        timeout=START_TIMEOUT_S,
    )
    return proc.returncode, proc.stdout + proc.stderr


PLANNER_PARAMS: dict[str, Any] = {
    "config": PLANNER_YAML,
    "frame_ack_consumer": "fast_planner",
    "label_every_frame": False,
}


@pytest.mark.parametrize(
    ("leave_out", "named"),
    [
        ("label_every_frame", "required parameter /fast_planner/label_every_frame is not set"),
        ("frame_ack_consumer", "required parameter /fast_planner/frame_ack_consumer is not set"),
        ("collector_output_dir", "required parameter /fast_planner/collector_output_dir is not set"),
    ],
)
def test_the_planner_node_names_a_missing_parameter(master: str, leave_out: str, named: str) -> None:
    params = dict(PLANNER_PARAMS, collector_output_dir="")
    del params[leave_out]
    code, out = run_node(master, "fast_planner", "fast_planner_node", "fast_planner", params)
    assert code == 1, out
    assert named in out, out


def test_recording_needs_the_collector_parameters_too(master: str, tmp_path: Path) -> None:
    params = dict(PLANNER_PARAMS, collector_output_dir=str(tmp_path / "data"))
    code, out = run_node(master, "fast_planner", "fast_planner_node", "fast_planner", params)
    assert code == 1, out
    assert "required parameter /fast_planner/collector_config is not set" in out, out


def test_a_parameter_of_the_wrong_type_is_named(master: str) -> None:
    params = dict(PLANNER_PARAMS, collector_output_dir="", label_every_frame="yes")
    code, out = run_node(master, "fast_planner", "fast_planner_node", "fast_planner", params)
    assert code == 1, out
    assert "parameter /fast_planner/label_every_frame has the wrong type" in out, out


def test_the_tracker_node_names_a_missing_parameter(master: str) -> None:
    params = {"tracker_config": str(ROOT / "config" / "tracker.yaml")}
    code, out = run_node(master, "kr_tracker", "kr_tracker_node", "kr_tracker", params)
    assert code == 1, out
    assert "required parameter ~vehicle_config" in out, out
