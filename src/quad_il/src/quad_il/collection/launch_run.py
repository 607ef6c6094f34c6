"""Run `roslaunch quad_il collect.launch` as a subprocess on a private master (tests and the benchmark).

The caller's environment must have the workspace sourced (roslaunch on PATH, the devel space on
ROS_PACKAGE_PATH).
"""

from __future__ import annotations

import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

from quad_il.tools.ports import free_port


@dataclass
class CollectRun:
    returncode: int
    wall_s: float
    log: str
    out_dir: Path


def collect_command(out_dir: str | os.PathLike, port: int, **launch_args: object) -> list[str]:
    args = [f"{k}:={v}" for k, v in launch_args.items()]
    return ["roslaunch", "-p", str(port), "quad_il", "collect.launch", f"output_dir:={out_dir}", *args]


def start_collect(
    out_dir: str | os.PathLike, log_path: str | os.PathLike, port: int | None = None, **launch_args: object
) -> tuple[subprocess.Popen, int]:
    """Start collect.launch on its own master (port: a free one); output to log_path."""
    port = port or free_port()
    env = dict(os.environ)
    env["ROS_MASTER_URI"] = f"http://localhost:{port}"
    log = open(log_path, "w")  # noqa: SIM115 - handed to the child
    proc = subprocess.Popen(
        collect_command(out_dir, port, **launch_args),
        stdout=log,
        stderr=subprocess.STDOUT,
        env=env,
        start_new_session=True,
    )
    log.close()
    return proc, port


def stop(proc: subprocess.Popen, timeout_s: float = 30.0) -> int:
    """SIGINT to roslaunch (it shuts its nodes down), then SIGKILL the whole group if it hangs."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    return proc.returncode


def run_collect(
    out_dir: str | os.PathLike, log_path: str | os.PathLike, timeout_s: float = 120.0, **launch_args: object
) -> CollectRun:
    """Run collect.launch to its end (the episode manager finishing ends it)."""
    t0 = time.monotonic()
    proc, _ = start_collect(out_dir, log_path, **launch_args)
    try:
        proc.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        stop(proc)
    wall = time.monotonic() - t0
    return CollectRun(proc.returncode, wall, Path(log_path).read_text(errors="replace"), Path(out_dir))
