"""The Python twin of the frame/odometry pairing rule (quad_il.frame_pairing) decides exactly as its C++ home,
quad_core/pairing.h, bound in quad_policy_py: on stamps at and around the rule's edges."""

from __future__ import annotations

import numpy as np
import pytest

from quad_il import frame_pairing

core = pytest.importorskip("quad_policy_py", reason="quad_policy_py is not built (make build)")

PERIOD_S = 0.005


def _edge_stamps(frame_s: float) -> list[float]:
    """Odometry stamps around the two edges of the frame's control period, to within the tolerances."""
    out = []
    for edge in (frame_s - PERIOD_S, frame_s):
        for d in (-1e-3, -2e-6, -1e-6, -5e-7, -2e-9, -1e-9, 0.0, 5e-10, 1e-9, 2e-9, 5e-7, 1e-6, 2e-6, 1e-3):
            out.append(edge + d)
    return out


@pytest.mark.parametrize("frame_s", [0.0, 1.0, 12.345, 1234.5675])
def test_python_rule_equals_the_cpp_rule_at_the_edges(frame_s: float) -> None:
    for stamp in _edge_stamps(frame_s):
        assert frame_pairing.period_arrived(stamp, frame_s, PERIOD_S) == core.odometry_covers_frame(
            stamp, frame_s, PERIOD_S
        ), f"cover: odometry {stamp!r}, frame {frame_s!r}"
        expected = core.odometry_covers_frame(
            stamp, frame_s, PERIOD_S
        ) and core.odometry_not_newer_than_frame(stamp, frame_s)
        assert frame_pairing.in_control_period(stamp, frame_s, PERIOD_S) == expected, stamp


def test_newest_at_or_before_equals_the_cpp_selection() -> None:
    rng = np.random.default_rng(3)
    stamps = np.round(np.cumsum(rng.uniform(0.004, 0.006, 200)), 9).tolist()
    for frame_s in [
        *stamps[::7],
        *(s + 5e-10 for s in stamps[::11]),
        *(s - 2e-9 for s in stamps[::13]),
        -1.0,
    ]:
        i = frame_pairing.newest_at_or_before(stamps, frame_s)
        allowed = [k for k, s in enumerate(stamps) if core.odometry_not_newer_than_frame(s, frame_s)]
        assert i == (allowed[-1] if allowed else -1), frame_s
