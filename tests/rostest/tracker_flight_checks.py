#!/usr/bin/env python3
"""rostest node: simulator + tracker. Take off with the line tracker (goto service), goto a second point, then
fly a circle B-spline sent through the TrackBspline action, checking arrival, the tracking error against the
tracker's own PositionCommand, the action result, the episode status and the lockstep statistics."""

from __future__ import annotations

import math
import threading
import time
import unittest
from collections.abc import Callable

import actionlib
import rospy
import rostest
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import Point
from nav_msgs.msg import Odometry

from quad_msgs.msg import EpisodeStatus, PositionCommand, SimStats, TrackBsplineAction, TrackBsplineGoal
from quad_msgs.srv import Goto

WALL_TIMEOUT_S = 90.0


def wait_for(predicate: Callable[[], bool], what: str, timeout_s: float = WALL_TIMEOUT_S) -> None:
    """Waits on wall time (the simulator owns ROS time and may run faster or slower than real time)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s (wall) waiting for {what}")
        time.sleep(0.02)


class Recorder:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.odom: dict[int, tuple[float, float, float]] = {}
        self.vel: tuple[float, float, float] = (0.0, 0.0, 0.0)
        self.last: tuple[float, float, float] | None = None
        self.cmds: dict[int, tuple[float, float, float]] = {}
        self.status: EpisodeStatus | None = None
        self.stats: SimStats | None = None
        rospy.Subscriber("odom", Odometry, self._on_odom, queue_size=1000)
        rospy.Subscriber("position_cmd", PositionCommand, self._on_cmd, queue_size=1000)
        rospy.Subscriber("sim/status", EpisodeStatus, self._on_status, queue_size=10)
        rospy.Subscriber("sim/stats", SimStats, self._on_stats, queue_size=10)

    def _on_odom(self, m: Odometry) -> None:
        p = m.pose.pose.position
        v = m.twist.twist.linear
        with self.lock:
            self.odom[m.header.stamp.to_nsec()] = (p.x, p.y, p.z)
            self.last = (p.x, p.y, p.z)
            self.vel = (v.x, v.y, v.z)

    def _on_cmd(self, m: PositionCommand) -> None:
        with self.lock:
            self.cmds[m.header.stamp.to_nsec()] = (m.position.x, m.position.y, m.position.z)

    def _on_status(self, m: EpisodeStatus) -> None:
        self.status = m

    def _on_stats(self, m: SimStats) -> None:
        self.stats = m

    def at(self, target: tuple[float, float, float], tol_m: float) -> bool:
        with self.lock:
            if self.last is None:
                return False
            return math.dist(self.last, target) < tol_m and math.hypot(*self.vel) < 0.05

    def tracking_errors(self, t0_ns: int, t1_ns: int) -> list[float]:
        """|odometry - reference| for every control period in [t0, t1] (the command answers that odometry)."""
        with self.lock:
            return [
                math.dist(self.odom[s], self.cmds[s])
                for s in self.cmds
                if t0_ns <= s <= t1_ns and s in self.odom
            ]


def circle_goal(
    center: tuple[float, float, float], radius_m: float, mean_speed_mps: float, start_delay_s: float
) -> tuple[TrackBsplineGoal, float, float]:
    """A uniform cubic B-spline once around a horizontal circle, at rest at its +x point at both ends.

    The angle follows u - sin(2 pi u) / (2 pi) (zero rate at both ends, peak speed twice the mean), so the
    vehicle speeds up and slows down smoothly."""
    n_arc = 60
    circumference = 2.0 * math.pi * radius_m
    dt = circumference / n_arc / mean_speed_mps
    pts = []
    for i in range(n_arc + 1):
        u = i / n_arc
        a = 2.0 * math.pi * (u - math.sin(2.0 * math.pi * u) / (2.0 * math.pi))
        pts.append(Point(center[0] + radius_m * math.cos(a), center[1] + radius_m * math.sin(a), center[2]))
    pts = [pts[0], pts[0], *pts, pts[-1], pts[-1]]  # tripled ends: zero velocity and acceleration there
    g = TrackBsplineGoal()
    g.bspline.order = 3
    g.bspline.traj_id = 1
    g.bspline.start_time = rospy.Time.now() + rospy.Duration(start_delay_s)
    g.bspline.knots = [dt * (i - 3) for i in range(len(pts) + 4)]
    g.bspline.pos_pts = pts
    duration = dt * (len(pts) - 3)
    return g, duration, circumference


class TrackerFlightTest(unittest.TestCase):
    def test_take_off_goto_and_fly_a_bspline_goal(self) -> None:
        rec = Recorder()
        rospy.wait_for_service("tracker/goto", 60.0)
        goto = rospy.ServiceProxy("tracker/goto", Goto)
        client = actionlib.SimpleActionClient("tracker/track_bspline", TrackBsplineAction)
        self.assertTrue(client.wait_for_server(rospy.Duration(60.0)), "no TrackBspline server")
        # The tracker has odometry once it answers it (a goto is refused before that).
        wait_for(
            lambda: rec.last is not None and len(rec.cmds) > 0, "odometry and the tracker's first command"
        )
        self.assertLess(rec.last[2], 0.2, "the vehicle should start on the ground")

        # Take-off with the line tracker.
        takeoff = (0.0, 0.0, 1.5)
        res = goto(Point(*takeoff), 0.0, 0.0, 0.0)
        self.assertTrue(res.success, res.message)
        wait_for(lambda: rec.at(takeoff, 0.05), "take-off to 1.5 m")

        # Goto with explicit limits and a yaw change.
        target = (2.0, 1.0, 2.0)
        res = goto(Point(*target), 0.5, 1.0, 1.0)
        self.assertTrue(res.success, res.message)
        wait_for(lambda: rec.at(target, 0.05), "goto (2, 1, 2)")

        # A circle of radius 1 m centred 1 m behind the current point, 1 m/s mean and 2 m/s peak speed.
        goal, duration, length = circle_goal((1.0, 1.0, 2.0), 1.0, 1.0, 0.3)
        feedback: list[float] = []
        client.send_goal(goal, feedback_cb=lambda fb: feedback.append(fb.remaining_time_s))
        t0 = goal.bspline.start_time.to_nsec()
        self.assertTrue(client.wait_for_result(rospy.Duration(duration + 30.0)), "no result")
        self.assertEqual(client.get_state(), GoalStatus.SUCCEEDED)
        result = client.get_result()
        self.assertTrue(result.success)
        self.assertEqual(result.reason, "")
        self.assertAlmostEqual(result.total_time_s, duration, delta=0.05)
        self.assertAlmostEqual(result.distance_travelled_m, length, delta=0.1 * length)
        self.assertGreater(len(feedback), 5)
        self.assertTrue(all(b <= a + 1e-9 for a, b in zip(feedback, feedback[1:], strict=False)))

        # In lockstep the simulator runs several times faster than real time, and this recorder is not a
        # lockstep peer: the result can arrive before the recorder has the circle's last odometry messages.
        t1 = t0 + int(duration * 1e9)

        def recorded_to_end() -> bool:
            with rec.lock:
                return bool(rec.odom) and max(rec.odom) >= t1 and bool(rec.cmds) and max(rec.cmds) >= t1

        wait_for(recorded_to_end, "odometry and commands up to the end of the circle")
        errors = rec.tracking_errors(t0, t1)
        self.assertGreater(len(errors), 0.9 * duration * 200)
        rms = math.sqrt(sum(e * e for e in errors) / len(errors))
        rospy.loginfo("circle: %d samples, RMS %.4f m, max %.4f m", len(errors), rms, max(errors))
        self.assertLess(rms, 0.05)
        self.assertLess(max(errors), 0.15)

        # The vehicle ends at rest at the circle's end point; nothing was hit; lockstep never waited in vain.
        wait_for(lambda: rec.at(target, 0.05), "rest at the end of the circle")
        self.assertIsNotNone(rec.status)
        self.assertFalse(rec.status.collided, rec.status.reason)
        wait_for(lambda: rec.stats is not None, "sim stats")
        self.assertEqual(rec.stats.lockstep_command_timeouts, 0)
        self.assertEqual(rec.stats.rejected_commands, 0)


if __name__ == "__main__":
    rospy.init_node("tracker_flight_checks")
    rostest.rosrun("quad_il", "tracker_flight", TrackerFlightTest)
