"""The frame/odometry pairing rule, once for all Python code (its C++ home is quad_core).

The state of an observation taken at a depth frame stamped t is the newest odometry stamped at or before t.
In lockstep the simulator publishes the odometry of a control period before the frame of that period, so the
odometry to wait for is the one of the frame's control period: stamped in (t - period, t]
(docs/CONVENTIONS.md, "Lockstep"). Odometry and depth arrive on different connections, so a consumer first
waits until `period_arrived` holds, then takes `newest_at_or_before`.

Stamps are ROS times (integral nanoseconds) converted to seconds; the two tolerances absorb the conversion's
rounding and are quad_core/pairing.h's (kPairingCoverEps, kPairingStampEps). Dependency-free on purpose:
rospy nodes, the collector and the policy node all import it; tests/python/test_frame_pairing.py checks it
against the C++ rule through the bindings (quad_policy_py).
"""

from __future__ import annotations

import bisect
from collections.abc import Sequence

COVER_EPS_S = 1e-6  # quad_core::kPairingCoverEps
STAMP_EPS_S = 1e-9  # quad_core::kPairingStampEps


def period_arrived(newest_stamp_s: float, frame_stamp_s: float, period_s: float) -> bool:
    """True once a message of the frame's control period (stamp > t - period) has arrived: nothing older than
    the frame's own odometry is still missing."""
    return newest_stamp_s > frame_stamp_s - period_s + COVER_EPS_S


def in_control_period(stamp_s: float, frame_stamp_s: float, period_s: float) -> bool:
    """The rule itself: stamp > t - period and stamp <= t."""
    return period_arrived(stamp_s, frame_stamp_s, period_s) and stamp_s <= frame_stamp_s + STAMP_EPS_S


def newest_at_or_before(stamps_s: Sequence[float], frame_stamp_s: float) -> int:
    """Index of the newest stamp <= t in ascending `stamps_s`; -1 when every stamp is newer (or none)."""
    return bisect.bisect_right(stamps_s, frame_stamp_s + STAMP_EPS_S) - 1
