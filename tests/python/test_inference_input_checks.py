"""The policy nodes' input checks (quad_policy/input_checks.h, bound as quad_il.inference.core: both nodes
return these texts, which tests/rostest/policy_bad_input.test compares node against node)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quad_il.inference.core import depth_layout_problem, depth_size_problem, state_problem

W, H = 80, 60


def test_a_little_endian_32fc1_frame_of_step_times_height_bytes_is_usable() -> None:
    assert depth_layout_problem("32FC1", False, W, H, 4 * W, 4 * W * H) == ""
    assert depth_layout_problem("32FC1", False, W, H, 4 * W + 8, (4 * W + 8) * H) == ""  # padded rows


@pytest.mark.parametrize(
    ("layout", "reason"),
    [
        (("16UC1", False, W, H, 2 * W, 2 * W * H), "depth frame encoding is '16UC1', not 32FC1"),
        (("rgb8", False, W, H, 3 * W, 3 * W * H), "depth frame encoding is 'rgb8', not 32FC1"),
        (("32FC1", True, W, H, 4 * W, 4 * W * H), "depth frame is big-endian (32FC1 little-endian needed)"),
        (("32FC1", False, 0, H, 0, 0), "depth frame is empty (0x60)"),
        (
            ("32FC1", False, W, H, 4 * W - 4, 4 * W * H),
            "depth frame step 316 is not a multiple of 4 of at least",
        ),
        (("32FC1", False, W, H, 4 * W + 2, (4 * W + 2) * H), "depth frame step 322 is not a multiple of 4"),
        (
            ("32FC1", False, W, H, 4 * W, 4 * W * (H - 1)),
            "depth frame has 18880 data bytes, step * height = 19200",
        ),
        (
            ("32FC1", False, W, H, 4 * W, 4 * W * (H + 1)),
            "depth frame has 19520 data bytes, step * height = 19200",
        ),
    ],
)
def test_every_other_layout_is_refused_naming_the_fault(layout: tuple, reason: str) -> None:
    assert depth_layout_problem(*layout).startswith(reason)


def test_a_frame_must_have_camera_infos_size() -> None:
    assert depth_size_problem(W, H, W, H) == ""
    assert depth_size_problem(40, 30, W, H) == "depth frame is 40x30, camera_info is 80x60"


def test_odometry_must_be_finite_and_the_reason_names_the_fields() -> None:
    p, v, q = np.array([1.0, 2.0, 3.0]), np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
    assert state_problem(p, v, q, 2.5) == ""
    assert (
        state_problem(np.array([math.nan, 0, 0]), v, q, 2.5)
        == "odometry at 2.500000 s is not finite (position)"
    )
    assert (
        state_problem(p, np.array([0, math.inf, 0]), np.array([0, 0, math.nan, 1]), 3.0)
        == "odometry at 3.000000 s is not finite (velocity, orientation)"
    )
