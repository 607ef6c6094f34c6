"""Checks of the inputs a policy node takes from ROS messages (issue 30: bad input is refused with a reason,
never decided on). Each returns "" when the input is usable, else the reason the frame is refused, published
on policy/decision (status bad_input). The C++ node (quad_policy/input_checks.h) returns the same texts."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray


def depth_layout_problem(
    encoding: str, is_bigendian: bool, width: int, height: int, step: int, data_bytes: int
) -> str:
    """A depth frame the nodes read: 32FC1 little-endian (metres, REP 118), not empty, rows of `step` bytes
    (a multiple of 4, at least 4 * width), exactly step * height bytes of data."""
    if encoding != "32FC1":
        return f"depth frame encoding is '{encoding}', not 32FC1"
    if is_bigendian:
        return "depth frame is big-endian (32FC1 little-endian needed)"
    if width == 0 or height == 0:
        return f"depth frame is empty ({width}x{height})"
    if step < 4 * width or step % 4:
        return f"depth frame step {step} is not a multiple of 4 of at least 4 * width = {4 * width}"
    if data_bytes != step * height:
        return f"depth frame has {data_bytes} data bytes, step * height = {step * height}"
    return ""


def depth_size_problem(width: int, height: int, info_width: int, info_height: int) -> str:
    """The frame's size must be camera_info's: the safety layer projects with that camera model."""
    if (width, height) == (info_width, info_height):
        return ""
    return f"depth frame is {width}x{height}, camera_info is {info_width}x{info_height}"


def state_problem(
    p: NDArray[np.float64], v: NDArray[np.float64], q_xyzw: NDArray[np.float64], stamp_s: float
) -> str:
    """Odometry the nodes decide from: finite position, velocity and orientation."""
    fields = [
        name
        for name, values in (("position", p), ("velocity", v), ("orientation", q_xyzw))
        if not np.all(np.isfinite(values))
    ]
    if not fields:
        return ""
    return f"odometry at {stamp_s:.6f} s is not finite ({', '.join(fields)})"
