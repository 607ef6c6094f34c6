#!/usr/bin/env python3
"""rostest node: sends the planner a goal 15 m away and waits for the simulator to report the episode's end.

Passes when the simulator reports the goal reached without a collision, and the planner produced trajectories
(planner/bspline), per-plan timings (planner/timing) and acknowledged depth frames (sim/frame_ack)."""

from __future__ import annotations

import threading
import unittest

import rospy
import rostest
from geometry_msgs.msg import PoseStamped

from quad_msgs.msg import Bspline, EpisodeStatus, FrameAck, PlanTiming


class PlannerFlightTest(unittest.TestCase):
    def setUp(self) -> None:
        self.lock = threading.Lock()
        self.ended = threading.Event()
        self.status: EpisodeStatus | None = None
        self.bsplines: list[Bspline] = []
        self.timings: list[PlanTiming] = []
        self.acks = 0
        rospy.Subscriber("sim/status", EpisodeStatus, self._on_status)
        rospy.Subscriber("planner/bspline", Bspline, self._on_bspline)
        rospy.Subscriber("planner/timing", PlanTiming, self._on_timing)
        rospy.Subscriber("sim/frame_ack", FrameAck, self._on_ack)
        self.goal_pub = rospy.Publisher("planner/goal", PoseStamped, queue_size=1, latch=True)

    def _on_status(self, msg: EpisodeStatus) -> None:
        with self.lock:
            self.status = msg
        if msg.episode_id > 0 and not msg.active:
            self.ended.set()

    def _on_bspline(self, msg: Bspline) -> None:
        with self.lock:
            self.bsplines.append(msg)

    def _on_timing(self, msg: PlanTiming) -> None:
        with self.lock:
            self.timings.append(msg)

    def _on_ack(self, msg: FrameAck) -> None:
        if msg.consumer == "fast_planner":
            with self.lock:
                self.acks += 1

    def test_flies_to_a_goal_15_m_away_without_collision(self) -> None:
        timeout = rospy.get_param("~timeout_wall_s", 240.0)
        # The goal is latched: the planner gets it whenever it subscribes.
        goal = PoseStamped()
        goal.header.frame_id = "world"
        goal.pose.position.x = rospy.get_param("~goal_x")
        goal.pose.position.y = rospy.get_param("~goal_y")
        goal.pose.position.z = rospy.get_param("~goal_z")
        goal.pose.orientation.w = 1.0
        self.goal_pub.publish(goal)
        self.assertTrue(self.ended.wait(timeout), f"the episode did not end within {timeout} s of wall time")
        with self.lock:
            status = self.status
            plans = len(self.bsplines)
            timings = list(self.timings)
            acks = self.acks
        assert status is not None
        self.assertFalse(status.collided, f"collision: {status.reason}")
        self.assertTrue(status.reached_goal, f"goal not reached: {status.reason}")
        self.assertGreater(plans, 1, "the planner should replan on the way")
        self.assertTrue(any(t.status.startswith("success") for t in timings))
        self.assertTrue(all(t.total_ms >= 0.0 for t in timings))
        self.assertGreater(acks, 30, "the planner must acknowledge the depth frames (lockstep)")
        for b in self.bsplines:
            self.assertEqual(b.order, 3)
            self.assertEqual(len(b.knots), len(b.pos_pts) + b.order + 1)


if __name__ == "__main__":
    rospy.init_node("planner_flight_check")
    rostest.rosrun("quad_il", "planner_flight", PlannerFlightTest)
