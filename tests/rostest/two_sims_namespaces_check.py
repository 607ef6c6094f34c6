#!/usr/bin/env python3
"""rostest node of two_sims_namespaces.test: two quad_sim_node instances in namespaces a and b are
independent.

Each namespace's status names the world seed its simulator was started with, then the seed of its own reset;
each namespace's odometry is at the start its own reset asked for; the two worlds (markers) differ; resetting
one simulator leaves the other's episode alone; each /clock (remapped into its namespace) advances.
Every wait ends on its condition; the wall-time limits are failure guards."""

import math
import threading
import time
import unittest

import rospy
import rostest
from geometry_msgs.msg import Point, Pose, Quaternion
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from visualization_msgs.msg import MarkerArray

from quad_msgs.msg import EpisodeStatus
from quad_msgs.srv import ResetEpisode

NAMESPACES = ("a", "b")
START_SEEDS = {"a": 11, "b": 22}
RESET_SEEDS = {"a": 101, "b": 202}
STARTS = {"a": (-5.0, 3.0), "b": (4.0, -6.0)}
GROUND_Z_M = 0.125


def wait_until(pred, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError("timed out waiting for " + what)
        time.sleep(0.02)


class TwoSimsTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("two_sims_namespaces_check")
        cls.lock = threading.Lock()
        cls.last = {}  # (namespace, kind) -> newest message
        for ns in NAMESPACES:
            for kind, topic, typ in (
                ("status", "sim/status", EpisodeStatus),
                ("odom", "odom", Odometry),
                ("markers", "sim/world_markers", MarkerArray),
                ("clock", "clock", Clock),
            ):
                rospy.Subscriber(f"{ns}/{topic}", typ, cls.keep, callback_args=(ns, kind), queue_size=10)
        cls.reset = {}
        for ns in NAMESPACES:
            rospy.wait_for_service(f"{ns}/sim/reset", timeout=60.0)
            cls.reset[ns] = rospy.ServiceProxy(f"{ns}/sim/reset", ResetEpisode)

    @classmethod
    def keep(cls, msg, key):
        with cls.lock:
            cls.last[key] = msg

    def get(self, ns, kind):
        with self.lock:
            return self.last.get((ns, kind))

    def test_each_namespace_talks_to_its_own_simulator(self):
        for ns in NAMESPACES:
            wait_until(lambda ns=ns: self.get(ns, "status") is not None, 30, f"{ns}/sim/status")
            wait_until(lambda ns=ns: self.get(ns, "markers") is not None, 30, f"{ns}/sim/world_markers")
            self.assertEqual(self.get(ns, "status").world_seed, START_SEEDS[ns], ns)
        # Different seeds, different worlds: the box markers differ.
        poses = {
            ns: [(m.pose.position.x, m.pose.position.y) for m in self.get(ns, "markers").markers]
            for ns in NAMESPACES
        }
        self.assertNotEqual(poses["a"], poses["b"])

        episode_b = self.get("b", "status").episode_id
        responses = {}
        for ns in NAMESPACES:
            x, y = STARTS[ns]
            start = Pose(position=Point(x, y, GROUND_Z_M), orientation=Quaternion(0.0, 0.0, 0.0, 1.0))
            responses[ns] = self.reset[ns](
                seed=RESET_SEEDS[ns], world_file="", start=start, goal=Point(x + 10.0, y, 1.5)
            )
            self.assertTrue(responses[ns].success, f"{ns}: {responses[ns].message}")
            if ns == "a":
                # a's reset did not touch b: b's episode is the same one until b is reset.
                self.assertEqual(self.get("b", "status").episode_id, episode_b)
                self.assertEqual(self.get("b", "status").world_seed, START_SEEDS["b"])
        for ns in NAMESPACES:
            eid = responses[ns].episode_id
            wait_until(
                lambda ns=ns, eid=eid: (s := self.get(ns, "status")) is not None and s.episode_id == eid,
                30,
                f"{ns}/sim/status of episode {eid}",
            )
            self.assertEqual(self.get(ns, "status").world_seed, RESET_SEEDS[ns], ns)
            x, y = STARTS[ns]

            def at_start(ns=ns, x=x, y=y):
                o = self.get(ns, "odom")
                return (
                    o is not None
                    and math.hypot(o.pose.pose.position.x - x, o.pose.pose.position.y - y) < 0.05
                )

            wait_until(at_start, 30, f"{ns}/odom at its own start {STARTS[ns]}")
        # Each simulator's clock, remapped into its namespace, advances.
        for ns in NAMESPACES:
            wait_until(lambda ns=ns: self.get(ns, "clock") is not None, 30, f"{ns}/clock")
            t0 = self.get(ns, "clock").clock
            wait_until(lambda ns=ns, t0=t0: self.get(ns, "clock").clock > t0, 30, f"{ns}/clock advancing")


if __name__ == "__main__":
    rostest.rosrun("quad_il", "two_sims_namespaces", TwoSimsTest)
