"""A virtual X display for rviz snapshots (ROS-free): start Xvfb, wait for a window, capture the screen until
the picture settles. Used by quad_il.evaluation.snapshot."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np


class SnapshotError(RuntimeError):
    """The snapshot could not be taken; the message says why."""


def start_xvfb(size: tuple[int, int]) -> tuple[subprocess.Popen, str]:
    read_fd, write_fd = os.pipe()
    proc = subprocess.Popen(
        ["Xvfb", "-displayfd", str(write_fd), "-screen", "0", f"{size[0]}x{size[1]}x24", "-nolisten", "tcp"],
        pass_fds=(write_fd,),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    os.close(write_fd)
    with os.fdopen(read_fd) as f:
        number = f.readline().strip()
    if not number:
        proc.kill()
        raise SnapshotError("Xvfb did not start")
    return proc, f":{number}"


def stop_process(proc: subprocess.Popen | None, sig: int = signal.SIGINT, wait_s: float = 10.0) -> None:
    if proc is None or proc.poll() is not None:
        return
    proc.send_signal(sig)
    try:
        proc.wait(wait_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


def window_up(display: str) -> bool:
    out = subprocess.run(
        ["xwininfo", "-root", "-tree"], env={**os.environ, "DISPLAY": display}, capture_output=True, text=True
    )
    return "RViz" in out.stdout or "rviz" in out.stdout


def capture(display: str, png: Path) -> np.ndarray:
    subprocess.run(
        ["import", "-display", display, "-window", "root", f"PNG24:{png}"], check=True, capture_output=True
    )
    if not png.is_file() or png.stat().st_size == 0:
        raise SnapshotError(f"import wrote no image to {png}")
    import matplotlib.image as mpimg

    return np.asarray(mpimg.imread(str(png)), dtype=np.float32)


def capture_settled(display: str, png: Path, settle_s: float, max_extra: int) -> None:
    """Capture until the picture stops changing: on a loaded machine rviz may still be receiving and drawing
    the world's markers after the fixed settle time. Up to `max_extra` further captures, `settle_s / 3`
    apart, until fewer than 0.5 % of the pixels change between two of them (a moving vehicle keeps changing
    a few)."""
    previous = capture(display, png)
    for _ in range(max_extra):
        time.sleep(max(0.2, settle_s / 3.0))
        current = capture(display, png)
        same_size = current.shape == previous.shape
        changed = float(np.any(np.abs(current - previous) > 0.05, axis=-1).mean()) if same_size else 1.0
        if changed < 0.005:
            return
        previous = current
