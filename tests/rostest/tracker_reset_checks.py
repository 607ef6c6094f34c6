#!/usr/bin/env python3
"""rostest node: episode resets under the tracker (quad_sim in lockstep + kr_tracker).

Take off, fly a B-spline goal and, while it runs, reset the simulator to a start on the ground elsewhere:
the goal must be aborted (reason "episode reset" or, if the odometry overtook the status, "odometry jump"),
the tracker's first reference of the new episode must be the new start, and the vehicle must stay there
instead of flying back. Then take off from the new start, reset mid-goto to an airborne start, check that
the vehicle holds it, and fly a new goto from it along a straight line."""

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
from geometry_msgs.msg import Point, Pose, Quaternion
from nav_msgs.msg import Odometry

from quad_msgs.msg import EpisodeStatus, PositionCommand, SimStats, TrackBsplineAction, TrackBsplineGoal
from quad_msgs.srv import Goto, ResetEpisode

WALL_TIMEOUT_S = 40.0
Vec = tuple[float, float, float]


def wait_for(predicate: Callable[[], bool], what: str, timeout_s: float = WALL_TIMEOUT_S) -> None:
    """Waits on wall time (the simulator owns ROS time)."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s (wall) waiting for {what}")
        time.sleep(0.01)


def point_segment_distance(p: Vec, a: Vec, b: Vec) -> float:
    ab = [b[i] - a[i] for i in range(3)]
    ap = [p[i] - a[i] for i in range(3)]
    den = sum(x * x for x in ab)
    u = 0.0 if den == 0.0 else max(0.0, min(1.0, sum(ab[i] * ap[i] for i in range(3)) / den))
    return math.dist(p, [a[i] + u * ab[i] for i in range(3)])


class Recorder:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.odom: dict[int, Vec] = {}
        self.last: Vec | None = None
        self.last_stamp = 0
        self.vel: Vec = (0.0, 0.0, 0.0)
        self.cmds: dict[int, tuple[Vec, float]] = {}
        self.statuses: dict[int, EpisodeStatus] = {}  # first status of each episode
        self.status: EpisodeStatus | None = None
        self.stats: SimStats | None = None
        rospy.Subscriber("odom", Odometry, self._on_odom, queue_size=2000)
        rospy.Subscriber("position_cmd", PositionCommand, self._on_cmd, queue_size=2000)
        rospy.Subscriber("sim/status", EpisodeStatus, self._on_status, queue_size=10)
        rospy.Subscriber("sim/stats", SimStats, self._on_stats, queue_size=10)

    def _on_odom(self, m: Odometry) -> None:
        p, v = m.pose.pose.position, m.twist.twist.linear
        with self.lock:
            self.odom[m.header.stamp.to_nsec()] = (p.x, p.y, p.z)
            self.last = (p.x, p.y, p.z)
            self.last_stamp = m.header.stamp.to_nsec()
            self.vel = (v.x, v.y, v.z)

    def _on_cmd(self, m: PositionCommand) -> None:
        with self.lock:
            self.cmds[m.header.stamp.to_nsec()] = ((m.position.x, m.position.y, m.position.z), m.yaw)

    def _on_status(self, m: EpisodeStatus) -> None:
        with self.lock:
            self.statuses.setdefault(m.episode_id, m)
            self.status = m

    def _on_stats(self, m: SimStats) -> None:
        self.stats = m

    def at(self, target: Vec, tol_m: float) -> bool:
        with self.lock:
            if self.last is None:
                return False
            return math.dist(self.last, target) < tol_m and math.hypot(*self.vel) < 0.05

    def stamp(self) -> int:
        with self.lock:
            return self.last_stamp

    def odom_between(self, t0_ns: int, t1_ns: int) -> list[Vec]:
        with self.lock:
            return [p for s, p in sorted(self.odom.items()) if t0_ns <= s <= t1_ns]


def line_goal(a: Vec, b: Vec, duration_s: float, start_delay_s: float) -> TrackBsplineGoal:
    """A uniform cubic B-spline from a to b, at rest at both ends (tripled end points)."""
    n_inner = 10
    pts = []
    for i in range(n_inner + 1):
        u = i / n_inner
        pts.append(Point(*[a[k] + u * (b[k] - a[k]) for k in range(3)]))
    pts = [pts[0], pts[0], *pts, pts[-1], pts[-1]]
    dt = duration_s / (len(pts) - 3)
    g = TrackBsplineGoal()
    g.bspline.order = 3
    g.bspline.traj_id = 11
    g.bspline.start_time = rospy.Time.now() + rospy.Duration(start_delay_s)
    g.bspline.knots = [dt * (i - 3) for i in range(len(pts) + 4)]
    g.bspline.pos_pts = pts
    return g


def yaw_quaternion(yaw: float) -> Quaternion:
    return Quaternion(0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


class TrackerResetTest(unittest.TestCase):
    def reset_and_check_hold(
        self, rec: Recorder, start: Vec, yaw: float, old: Vec, tol_m: float, during: str
    ) -> None:
        """Resets to `start` and checks 2 s (sim) of the new episode: the tracker's first reference is the new
        start pose and the vehicle stays within tol_m of it (it does not head back towards `old`)."""
        res = self.reset_srv(
            seed=0, world_file="", start=Pose(Point(*start), yaw_quaternion(yaw)), goal=Point(-4.0, -4.0, 4.0)
        )
        self.assertTrue(res.success, res.message)
        wait_for(lambda: res.episode_id in rec.statuses, f"the status of episode {res.episode_id}")
        t0 = rec.statuses[res.episode_id].sim_time.to_nsec()
        wait_for(lambda: rec.stamp() >= t0 + int(2.0e9), "2 s of the new episode")
        with rec.lock:
            first_ref = rec.cmds.get(t0)
        self.assertIsNotNone(first_ref, "no PositionCommand answered the new episode's first odometry")
        self.assertLess(math.dist(first_ref[0], start), 0.01, f"first reference after the reset ({during})")
        self.assertLess(abs(math.remainder(first_ref[1] - yaw, 2 * math.pi)), 0.01)
        track = rec.odom_between(t0, t0 + int(2.0e9))
        self.assertGreater(len(track), 350)
        worst = max(math.dist(p, start) for p in track)
        closest_to_old = min(math.dist(p, old) for p in track)
        rospy.loginfo("reset %s: max distance from the new start %.4f m over 2 s", during, worst)
        self.assertLess(worst, tol_m, f"the vehicle left the new start after the reset ({during})")
        self.assertGreater(closest_to_old, math.dist(start, old) - tol_m)
        status = rec.status
        self.assertEqual(status.episode_id, res.episode_id)
        self.assertFalse(status.collided, status.reason)

    def test_reset_re_anchors_the_tracker(self) -> None:
        rec = Recorder()
        rospy.wait_for_service("tracker/goto", 60.0)
        rospy.wait_for_service("sim/reset", 60.0)
        goto = rospy.ServiceProxy("tracker/goto", Goto)
        self.reset_srv = rospy.ServiceProxy("sim/reset", ResetEpisode)
        client = actionlib.SimpleActionClient("tracker/track_bspline", TrackBsplineAction)
        self.assertTrue(client.wait_for_server(rospy.Duration(60.0)), "no TrackBspline server")
        # The tracker has odometry once it answers it (the goto is refused before that).
        wait_for(
            lambda: rec.last is not None and len(rec.cmds) > 0, "odometry and the tracker's first command"
        )

        # Episode 1: take off, then fly a B-spline goal towards (2, 1, 2).
        takeoff = (0.0, 0.0, 1.5)
        self.assertTrue(goto(Point(*takeoff), 0.0, 0.0, 0.0).success)
        wait_for(lambda: rec.at(takeoff, 0.05), "take-off to 1.5 m")
        goal = line_goal(takeoff, (2.0, 1.0, 2.0), 4.0, 0.2)
        client.send_goal(goal)
        t_mid = goal.bspline.start_time.to_nsec() + int(1.5e9)
        wait_for(lambda: rec.stamp() >= t_mid, "the goal half way")
        self.assertEqual(client.get_state(), GoalStatus.ACTIVE)
        old = rec.last

        # Reset to a start on the ground 4.5 m away while the goal runs.
        ground_start = (-3.0, 2.0, 0.125)
        self.reset_and_check_hold(rec, ground_start, 1.0, old, 0.03, "to the ground, B-spline goal running")
        self.assertTrue(client.wait_for_result(rospy.Duration(10.0)), "no result for the running goal")
        self.assertEqual(client.get_state(), GoalStatus.ABORTED)
        reason = client.get_result().reason
        rospy.loginfo("goal result after the reset: %s", reason)
        self.assertTrue("episode reset" in reason or "odometry jump" in reason, reason)

        # Take off from the new start: straight up (the line tracker starts from the new position).
        t_goto = rec.stamp()
        above = (ground_start[0], ground_start[1], 1.2)
        self.assertTrue(goto(Point(*above), 1.0, 0.0, 0.0).success)
        wait_for(lambda: rec.at(above, 0.05), "take-off from the new start")
        climb = rec.odom_between(t_goto, rec.stamp())
        self.assertLess(max(math.hypot(p[0] - above[0], p[1] - above[1]) for p in climb), 0.05)

        # Reset mid-goto to an airborne start.
        self.assertTrue(goto(Point(-3.0, -2.0, 1.5), 1.0, 0.0, 0.0).success)
        t_go = rec.stamp()
        wait_for(lambda: rec.stamp() >= t_go + int(1.0e9), "the goto under way")
        old = rec.last
        air_start = (1.5, -3.0, 1.5)
        self.reset_and_check_hold(rec, air_start, -0.8, old, 0.10, "airborne, goto running")

        # A new goto from the airborne start flies the straight line from there.
        target = (2.5, -2.0, 1.8)
        t_goto = rec.stamp()
        self.assertTrue(goto(Point(*target), -0.8, 0.0, 0.0).success)
        wait_for(lambda: rec.at(target, 0.05), "goto from the airborne start")
        path = rec.odom_between(t_goto, rec.stamp())
        deviation = max(point_segment_distance(p, air_start, target) for p in path)
        rospy.loginfo("goto after the airborne reset: max deviation from the line %.4f m", deviation)
        self.assertLess(deviation, 0.10)

        wait_for(lambda: rec.stats is not None, "sim stats")
        self.assertEqual(rec.stats.lockstep_command_timeouts, 0)
        self.assertEqual(rec.stats.rejected_commands, 0)


if __name__ == "__main__":
    rospy.init_node("tracker_reset_checks")
    rostest.rosrun("quad_il", "tracker_reset", TrackerResetTest)
