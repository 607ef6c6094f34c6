#!/usr/bin/env python3
"""rostest node for kr_tracker_node without a simulator.

This node plays the odometry source (a vehicle at rest at (0, 0, 1)) and checks the node's protocol: one
SO3Command per odometry message with the same stamp, hover force m g, rejection of every malformed
TrackBspline goal with its reason, the switch/goto services, the safe command held while odometry is stale,
and non-finite odometry answered with the safe command."""

from __future__ import annotations

import math
import threading
import unittest
from collections.abc import Callable

import actionlib
import rospy
import rostest
from actionlib_msgs.msg import GoalStatus
from geometry_msgs.msg import Point
from nav_msgs.msg import Odometry

from quad_msgs.msg import SO3Command, TrackBsplineAction, TrackBsplineGoal
from quad_msgs.srv import Goto, SwitchTracker

MASS_KG = 0.75  # config/vehicle.yaml
GRAVITY = 9.81
P0 = (0.0, 0.0, 1.0)


class OdomSource:
    """Publishes odometry of a vehicle at rest at P0 at 200 Hz (wall clock); records the commands."""

    def __init__(self) -> None:
        self.pub = rospy.Publisher("odom", Odometry, queue_size=100)
        self.lock = threading.Lock()
        self.sent_stamps: list[rospy.Time] = []
        self.cmds: list[SO3Command] = []
        self.running = True
        self.nan_next = False
        rospy.Subscriber("so3_cmd", SO3Command, self._on_cmd, queue_size=1000)
        self.timer = rospy.Timer(rospy.Duration(0.005), self._tick)

    def _on_cmd(self, msg: SO3Command) -> None:
        with self.lock:
            self.cmds.append(msg)

    def _tick(self, _event: rospy.timer.TimerEvent) -> None:
        if not self.running or rospy.is_shutdown():
            return
        m = Odometry()
        m.header.stamp = rospy.Time.now()
        m.header.frame_id = "world"
        m.child_frame_id = "base_link"
        m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z = P0
        m.pose.pose.orientation.w = 1.0
        if self.nan_next:
            m.pose.pose.position.x = float("nan")
            self.nan_next = False
        with self.lock:
            self.sent_stamps.append(m.header.stamp)
        self.pub.publish(m)

    def snapshot(self) -> tuple[list[rospy.Time], list[SO3Command]]:
        with self.lock:
            return list(self.sent_stamps), list(self.cmds)


def wait_for(predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
    deadline = rospy.Time.now() + rospy.Duration(timeout_s)
    rate = rospy.Rate(50)
    while not predicate():
        if rospy.Time.now() > deadline:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        rate.sleep()


def line_goal(start_offset_s: float, order: int = 3, n: int = 8) -> TrackBsplineGoal:
    """A slow uniform B-spline along +x from P0 (valid unless modified by the caller)."""
    g = TrackBsplineGoal()
    b = g.bspline
    b.order = order
    b.traj_id = 11
    b.start_time = rospy.Time.now() + rospy.Duration(start_offset_s)
    b.knots = [0.5 * (i - order) for i in range(n + order + 1)]
    b.pos_pts = [Point(P0[0] + 0.1 * (i - 1), P0[1], P0[2]) for i in range(n)]
    return g


class TrackerNodeTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        cls.odom = OdomSource()
        cls.client = actionlib.SimpleActionClient("tracker/track_bspline", TrackBsplineAction)
        assert cls.client.wait_for_server(rospy.Duration(30.0)), "no TrackBspline action server"
        rospy.wait_for_service("tracker/switch", 30.0)
        rospy.wait_for_service("tracker/goto", 30.0)
        wait_for(lambda: len(cls.odom.snapshot()[1]) > 50, 30.0, "the first commands")

    @classmethod
    def tearDownClass(cls) -> None:
        cls.odom.running = False
        cls.odom.timer.shutdown()

    def test_1_one_command_per_odometry_with_its_stamp_and_hover_force(self) -> None:
        stamps, cmds = self.odom.snapshot()
        sent = {s.to_nsec() for s in stamps}
        cmd_stamps = [c.header.stamp.to_nsec() for c in cmds]
        self.assertEqual(len(cmd_stamps), len(set(cmd_stamps)), "two commands for one odometry stamp")
        self.assertTrue(set(cmd_stamps) <= sent, "a command whose stamp is no odometry stamp")
        last = cmds[-1]
        self.assertAlmostEqual(last.force.z, MASS_KG * GRAVITY, places=6)
        self.assertAlmostEqual(math.hypot(last.force.x, last.force.y), 0.0, places=6)
        self.assertAlmostEqual(last.orientation.w, 1.0, places=6)
        self.assertEqual(list(last.kR), [1.5, 1.5, 1.0])
        self.assertTrue(last.aux.enable_motors)

    def _rejected(self, goal: TrackBsplineGoal) -> str:
        self.client.send_goal(goal)
        self.assertTrue(self.client.wait_for_result(rospy.Duration(10.0)))
        self.assertEqual(self.client.get_state(), GoalStatus.REJECTED)
        result = self.client.get_result()
        self.assertFalse(result.success)
        return result.reason

    def test_2_every_malformed_goal_is_rejected_with_its_reason(self) -> None:
        g = line_goal(0.2)
        g.bspline.knots[4], g.bspline.knots[5] = g.bspline.knots[5], g.bspline.knots[4] - 1.0
        self.assertIn("knots are not non-decreasing", self._rejected(g))
        g = line_goal(0.2)
        g.bspline.knots.pop()
        self.assertIn("knot count 11 != control points + order + 1", self._rejected(g))
        g = line_goal(0.2)
        g.bspline.pos_pts[3].y = float("nan")
        self.assertIn("control point 3 is not finite", self._rejected(g))
        g = line_goal(0.2)
        g.bspline.knots[2] = float("inf")
        self.assertIn("knot 2 is not finite", self._rejected(g))
        g = line_goal(0.2)
        g.bspline.yaw_pts = [0.0, 0.1, float("nan"), 0.2]
        g.bspline.yaw_dt = 0.5
        self.assertIn("yaw point 2 is not finite", self._rejected(g))
        g = line_goal(0.2)
        g.bspline.order = 0
        g.bspline.knots = g.bspline.knots[:9]
        self.assertIn("order (degree) 0 is below 1", self._rejected(g))
        self.assertIn("s in the future (limit 2 s)", self._rejected(line_goal(60.0)))
        self.assertIn("s in the past (limit 1 s)", self._rejected(line_goal(-30.0)))

    def test_3_a_valid_goal_is_flown_to_success_with_time_and_distance(self) -> None:
        self.client.send_goal(line_goal(0.1))
        self.assertTrue(self.client.wait_for_result(rospy.Duration(20.0)))
        self.assertEqual(self.client.get_state(), GoalStatus.SUCCEEDED)
        r = self.client.get_result()
        self.assertTrue(r.success)
        self.assertEqual(r.reason, "")
        self.assertAlmostEqual(r.total_time_s, 2.5, delta=0.1)  # (8 - 3) * 0.5 s
        self.assertAlmostEqual(r.distance_travelled_m, 0.0, places=6)  # this "vehicle" does not move

    def test_4_services_switch_and_goto(self) -> None:
        switch = rospy.ServiceProxy("tracker/switch", SwitchTracker)
        res = switch("mpc")
        self.assertFalse(res.success)
        self.assertIn("unknown tracker 'mpc'", res.message)
        self.assertTrue(switch("hover").success)
        goto = rospy.ServiceProxy("tracker/goto", Goto)
        res = goto(Point(float("nan"), 0.0, 1.0), 0.0, 0.0, 0.0)
        self.assertFalse(res.success)
        self.assertEqual(res.message, "goal position is not finite")
        self.assertTrue(goto(Point(0.0, 0.0, 2.0), 0.0, 1.0, 1.0).success)
        # The line tracker now pulls upwards: more thrust than the weight.
        wait_for(lambda: self.odom.snapshot()[1][-1].force.z > MASS_KG * GRAVITY + 0.01, 5.0, "climb command")
        self.assertTrue(switch("hover").success)

    def test_5_non_finite_odometry_is_answered_with_the_safe_command(self) -> None:
        n_before = len(self.odom.snapshot()[1])
        self.odom.nan_next = True
        wait_for(lambda: len(self.odom.snapshot()[1]) > n_before + 20, 5.0, "commands after the NaN odometry")
        stamps, cmds = self.odom.snapshot()
        for c in cmds[n_before:]:
            self.assertTrue(all(math.isfinite(v) for v in (c.force.x, c.force.y, c.force.z)))

    def test_6_stale_odometry_holds_the_safe_hover_command(self) -> None:
        self.odom.running = False
        rospy.sleep(0.3)  # longer than node.odom_timeout_s = 0.1 s
        stamps, cmds = self.odom.snapshot()
        n = len(cmds)
        wait_for(lambda: len(self.odom.snapshot()[1]) > n + 10, 5.0, "held commands while odometry is stale")
        _, cmds = self.odom.snapshot()
        sent = {s.to_nsec() for s in stamps}
        held = cmds[n:]
        self.assertTrue(all(c.header.stamp.to_nsec() not in sent for c in held))
        for c in held:
            self.assertAlmostEqual(c.force.z, MASS_KG * GRAVITY, places=6)
            self.assertAlmostEqual(math.hypot(c.force.x, c.force.y), 0.0, places=6)
        self.odom.running = True


if __name__ == "__main__":
    rospy.init_node("tracker_node_checks")
    rostest.rosrun("quad_il", "tracker_node_checks", TrackerNodeTest)
