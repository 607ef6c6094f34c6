#!/usr/bin/env python3
"""rostest node for kr_tracker_node without a simulator.

This node plays the odometry source (a vehicle at rest at (0, 0, 1)) and checks the node's protocol: one
SO3Command per odometry message with the same stamp, hover force m g, rejection of every malformed
TrackBspline goal with its reason, the switch/goto services, the safe command held while odometry is stale,
and non-finite odometry answered with the hold (issue 30): the hover command at the last good reference's yaw
and that reference held, after which tracking goes on as before. Every wait ends on its condition; the
timeouts are failure guards only."""

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

from quad_msgs.msg import PositionCommand, SO3Command, TrackBsplineAction, TrackBsplineGoal
from quad_msgs.srv import Goto, SwitchTracker

MASS_KG = 0.75  # config/vehicle.yaml
GRAVITY = 9.81
P0 = (0.0, 0.0, 1.0)
GUARD_S = 60.0  # wall-time failure guard of the waits


class OdomSource:
    """Publishes odometry of a vehicle at rest at P0 at 200 Hz (wall clock); records the commands."""

    def __init__(self) -> None:
        self.pub = rospy.Publisher("odom", Odometry, queue_size=100)
        self.lock = threading.Lock()
        self.sent_stamps: list[rospy.Time] = []
        self.cmds: list[SO3Command] = []
        self.refs: dict[int, PositionCommand] = {}  # by stamp (ns)
        self.running = True
        # Faults applied to the next odometry messages, one each; the stamps they went out with.
        self.faults: list[Callable[[Odometry], None]] = []
        self.fault_stamps: list[rospy.Time] = []
        rospy.Subscriber("so3_cmd", SO3Command, self._on_cmd, queue_size=1000)
        rospy.Subscriber("position_cmd", PositionCommand, self._on_ref, queue_size=1000)
        self.timer = rospy.Timer(rospy.Duration(0.005), self._tick)

    def _on_cmd(self, msg: SO3Command) -> None:
        with self.lock:
            self.cmds.append(msg)

    def _on_ref(self, msg: PositionCommand) -> None:
        with self.lock:
            self.refs[msg.header.stamp.to_nsec()] = msg

    def _tick(self, _event: rospy.timer.TimerEvent) -> None:
        if not self.running or rospy.is_shutdown():
            return
        m = Odometry()
        m.header.stamp = rospy.Time.now()
        m.header.frame_id = "world"
        m.child_frame_id = "base_link"
        m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z = P0
        m.pose.pose.orientation.w = 1.0
        with self.lock:
            if self.faults:
                self.faults.pop(0)(m)
                self.fault_stamps.append(m.header.stamp)
            self.sent_stamps.append(m.header.stamp)
        self.pub.publish(m)

    def snapshot(self) -> tuple[list[rospy.Time], list[SO3Command]]:
        with self.lock:
            return list(self.sent_stamps), list(self.cmds)


def wait_for(predicate: Callable[[], bool], what: str) -> None:
    """Polls the condition; GUARD_S (wall time) only fails a test whose condition never comes."""
    deadline = rospy.Time.now() + rospy.Duration(GUARD_S)
    rate = rospy.Rate(50)
    while not predicate():
        if rospy.Time.now() > deadline:
            raise AssertionError(f"timed out after {GUARD_S} s waiting for {what}")
        rate.sleep()


def yaw_of(q) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


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
        assert cls.client.wait_for_server(rospy.Duration(GUARD_S)), "no TrackBspline action server"
        rospy.wait_for_service("tracker/switch", GUARD_S)
        rospy.wait_for_service("tracker/goto", GUARD_S)
        wait_for(lambda: len(cls.odom.snapshot()[1]) > 50, "the first commands")

    @classmethod
    def tearDownClass(cls) -> None:
        cls.odom.running = False
        cls.odom.timer.shutdown()

    def test_1_one_command_per_odometry_with_its_stamp_and_hover_force(self) -> None:
        stamps, cmds = self.odom.snapshot()
        sent = {s.to_nsec() for s in stamps}
        answers = [c.header.stamp.to_nsec() for c in cmds if c.header.stamp.to_nsec() in sent]
        self.assertEqual(len(answers), len(set(answers)), "two commands for one odometry stamp")
        # Commands with any other stamp can only be the watchdog's hold, if this process's 200 Hz timer
        # stalled past node.odom_timeout_s on a loaded machine: hover force, nothing else.
        for c in cmds:
            if c.header.stamp.to_nsec() not in sent:
                self.assertAlmostEqual(c.force.z, MASS_KG * GRAVITY, places=6, msg="a command of no odometry")
                self.assertAlmostEqual(math.hypot(c.force.x, c.force.y), 0.0, places=6)
        last = next(c for c in reversed(cmds) if c.header.stamp.to_nsec() in sent)
        self.assertAlmostEqual(last.force.z, MASS_KG * GRAVITY, places=6)
        self.assertAlmostEqual(math.hypot(last.force.x, last.force.y), 0.0, places=6)
        self.assertAlmostEqual(last.orientation.w, 1.0, places=6)
        self.assertEqual(list(last.kR), [1.5, 1.5, 1.0])
        self.assertTrue(last.aux.enable_motors)

    def _rejected(self, goal: TrackBsplineGoal) -> str:
        self.client.send_goal(goal)
        self.assertTrue(self.client.wait_for_result(rospy.Duration(GUARD_S)))
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
        self.assertTrue(self.client.wait_for_result(rospy.Duration(GUARD_S)))
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
        wait_for(lambda: self.odom.snapshot()[1][-1].force.z > MASS_KG * GRAVITY + 0.01, "climb command")
        self.assertTrue(switch("hover").success)

    def test_5_non_finite_odometry_is_answered_with_the_hold(self) -> None:
        """While the line tracker climbs and turns (the "vehicle" does not move, so the commands pull up and
        turn), three odometry messages come with a NaN position, an inf velocity and a NaN orientation. Each
        is answered, with its own stamp, by the hold: weight-compensating thrust straight up, level attitude
        at the last good reference's yaw, and that reference held still (position, yaw, zero velocity).
        Then the climb goes on from where it was."""
        self.assertTrue(rospy.ServiceProxy("tracker/goto", Goto)(Point(0.0, 0.0, 3.0), 0.6, 0.5, 0.5).success)

        def moving() -> bool:
            with self.odom.lock:
                refs = sorted(self.odom.refs.items())
            return bool(refs) and refs[-1][1].velocity.z > 0.2 and refs[-1][1].yaw > 0.2

        wait_for(moving, "the climb and turn to be under way")

        def position_nan(m: Odometry) -> None:
            m.pose.pose.position.x = float("nan")

        def velocity_inf(m: Odometry) -> None:
            m.twist.twist.linear.z = float("inf")

        def orientation_nan(m: Odometry) -> None:
            m.pose.pose.orientation.z = float("nan")

        with self.odom.lock:
            self.odom.faults = [position_nan, velocity_inf, orientation_nan]
            self.odom.fault_stamps = []

        def answered() -> bool:
            with self.odom.lock:
                if len(self.odom.fault_stamps) < 3:
                    return False
                last = self.odom.fault_stamps[-1]
                return sum(c.header.stamp > last for c in self.odom.cmds) >= 20

        wait_for(answered, "the answers to the faulty odometry and 20 commands after them")
        with self.odom.lock:
            faults = [s.to_nsec() for s in self.odom.fault_stamps]
            cmds = list(self.odom.cmds)
            refs = dict(self.odom.refs)
            # Answers to odometry (not the watchdog's holds, should this process's timer stall).
            sent = {s.to_nsec() for s in self.odom.sent_stamps}
        by_stamp: dict[int, list[SO3Command]] = {}
        for c in cmds:
            by_stamp.setdefault(c.header.stamp.to_nsec(), []).append(c)
        good = sorted(s for s in refs if s < faults[0] and s in sent)
        before = refs[good[-1]]  # the last good reference
        before_cmd = by_stamp[good[-1]][-1]
        # The last good command was pulling up (the reference climbs away from the vehicle): not a hover.
        self.assertGreater(before_cmd.force.z, MASS_KG * GRAVITY + 0.05)
        self.assertGreater(abs(before.yaw), 0.2)
        for stamp in faults:
            self.assertEqual(len(by_stamp.get(stamp, [])), 1, f"answers to the odometry stamped {stamp}")
            c = by_stamp[stamp][0]
            self.assertEqual((c.force.x, c.force.y), (0.0, 0.0))
            self.assertAlmostEqual(c.force.z, MASS_KG * GRAVITY, places=9)
            q = c.orientation
            self.assertAlmostEqual(math.hypot(q.x, q.y), 0.0, places=9)  # level
            self.assertAlmostEqual(yaw_of(q), before.yaw, places=9)  # at the last good yaw
            self.assertTrue(c.aux.enable_motors)
            r = refs[stamp]
            self.assertEqual(
                (r.position.x, r.position.y, r.position.z, r.yaw),
                (before.position.x, before.position.y, before.position.z, before.yaw),
            )
            self.assertEqual((r.velocity.x, r.velocity.y, r.velocity.z), (0.0, 0.0, 0.0))
            self.assertEqual((r.acceleration.x, r.acceleration.y, r.acceleration.z), (0.0, 0.0, 0.0))
        # Afterwards tracking goes on from where it was: finite commands pulling up again, the reference
        # continuing the climb from the last good one.
        after = sorted(s for s in refs if s > faults[-1] and s in sent)
        self.assertGreaterEqual(refs[after[0]].position.z, before.position.z)
        for s in after:
            for c in by_stamp[s]:
                self.assertTrue(all(math.isfinite(v) for v in (c.force.x, c.force.y, c.force.z)))
        self.assertGreater(by_stamp[after[0]][-1].force.z, MASS_KG * GRAVITY + 0.05)
        self.assertTrue(rospy.ServiceProxy("tracker/switch", SwitchTracker)("hover").success)

    def test_6_stale_odometry_holds_the_safe_hover_command(self) -> None:
        with self.odom.lock:
            self.odom.running = False
            n = len(self.odom.cmds)

        def held() -> list[SO3Command]:
            # Commands answering no odometry: the watchdog's, once node.odom_timeout_s has passed.
            stamps, cmds = self.odom.snapshot()
            sent = {s.to_nsec() for s in stamps}
            return [c for c in cmds[n:] if c.header.stamp.to_nsec() not in sent]

        wait_for(lambda: len(held()) > 10, "held commands while odometry is stale")
        for c in held():
            self.assertAlmostEqual(c.force.z, MASS_KG * GRAVITY, places=6)
            self.assertAlmostEqual(math.hypot(c.force.x, c.force.y), 0.0, places=6)
        self.odom.running = True


if __name__ == "__main__":
    rospy.init_node("tracker_node_checks")
    rostest.rosrun("quad_il", "tracker_node_checks", TrackerNodeTest)
