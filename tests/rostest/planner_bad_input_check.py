#!/usr/bin/env python3
"""rostest node: bad input to fast_planner_node is skipped or rejected with a reason, never fatal."""

from __future__ import annotations

import threading
import unittest
from collections.abc import Callable

import rospy
import rostest
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import Image
from std_msgs.msg import String

from quad_msgs.msg import FrameAck

WAIT_S = 20.0


class PlannerBadInputTest(unittest.TestCase):
    def setUp(self) -> None:
        self.lock = threading.Lock()
        self.logs: list[str] = []
        self.statuses: list[str] = []
        self.acks: list[FrameAck] = []
        rospy.Subscriber("/rosout", Log, self._on_log, queue_size=100)
        rospy.Subscriber("planner/status", String, self._on_status, queue_size=100)
        rospy.Subscriber("sim/frame_ack", FrameAck, self._on_ack, queue_size=100)
        self.odom_pub = rospy.Publisher("odom", Odometry, queue_size=10)
        self.depth_pub = rospy.Publisher("camera/depth/image", Image, queue_size=10)
        self.goal_pub = rospy.Publisher("planner/goal", PoseStamped, queue_size=10)
        self.wait_for(
            lambda: all(p.get_num_connections() > 0 for p in (self.odom_pub, self.depth_pub, self.goal_pub)),
            "the planner node did not subscribe",
        )

    def _on_log(self, msg: Log) -> None:
        if msg.name.endswith("fast_planner"):
            with self.lock:
                self.logs.append(msg.msg)

    def _on_status(self, msg: String) -> None:
        with self.lock:
            self.statuses.append(msg.data)

    def _on_ack(self, msg: FrameAck) -> None:
        with self.lock:
            self.acks.append(msg)

    def wait_for(self, condition: Callable[[], bool], what: str) -> None:
        deadline = rospy.Time.now() + rospy.Duration(WAIT_S)
        rate = rospy.Rate(20)
        while not rospy.is_shutdown() and rospy.Time.now() < deadline:
            with self.lock:
                if condition():
                    return
            rate.sleep()
        self.fail(what)

    def publish_goal(self, x: float, y: float, z: float) -> None:
        g = PoseStamped()
        g.header.frame_id = "world"
        g.pose.position.x, g.pose.position.y, g.pose.position.z = x, y, z
        g.pose.orientation.w = 1.0
        self.goal_pub.publish(g)

    def test_bad_input_is_skipped_or_rejected_with_a_reason(self) -> None:
        # Non-finite odometry: skipped with a log line.
        odom = Odometry()
        odom.header.stamp = rospy.Time.now()
        odom.header.frame_id = "world"
        odom.pose.pose.position.x = float("nan")
        odom.pose.pose.orientation.w = 1.0
        self.odom_pub.publish(odom)
        self.wait_for(
            lambda: any("skipping odometry" in m and "not finite" in m for m in self.logs),
            "no log line for the NaN odometry",
        )
        # A 16-bit depth frame: skipped with a log line, but acknowledged (lockstep must not stall).
        img = Image()
        img.header.stamp = rospy.Time.now()
        img.header.frame_id = "camera"
        img.height, img.width = 4, 4
        img.encoding = "16UC1"
        img.step = 8
        img.data = bytes(32)
        self.depth_pub.publish(img)
        self.wait_for(
            lambda: any("skipping depth frame with encoding '16UC1'" in m for m in self.logs),
            "no log line for the 16UC1 depth frame",
        )
        self.wait_for(
            lambda: any(a.consumer == "fast_planner" and a.stamp == img.header.stamp for a in self.acks),
            "the bad frame was not acknowledged",
        )
        # Goals outside the map or in an obstacle (below the ground): rejected with the reason.
        self.publish_goal(500.0, 0.0, 1.5)
        self.wait_for(
            lambda: any(s.startswith("goal rejected:") and "outside the map" in s for s in self.statuses),
            "the goal outside the map was not rejected with its reason",
        )
        self.publish_goal(1.0, 0.0, -0.3)
        self.wait_for(
            lambda: any("goal rejected: goal is inside an obstacle" in s for s in self.statuses),
            "the goal below the ground was not rejected with its reason",
        )
        # Still alive: a goal in another frame is rejected too.
        g = PoseStamped()
        g.header.frame_id = "map"
        g.pose.orientation.w = 1.0
        self.goal_pub.publish(g)
        self.wait_for(
            lambda: any("frame 'map' is not 'world'" in s for s in self.statuses),
            "the goal in frame 'map' was accepted",
        )


if __name__ == "__main__":
    rospy.init_node("planner_bad_input_check")
    rostest.rosrun("quad_il", "planner_bad_input", PlannerBadInputTest)
