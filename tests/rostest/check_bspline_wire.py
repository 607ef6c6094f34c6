#!/usr/bin/env python3
"""rostest node: receives the Bspline published by the C++ bspline_test_publisher and checks every field."""

import threading
import unittest

import rospy
import rostest

from quad_msgs.msg import Bspline


class BsplineWireTest(unittest.TestCase):
    def test_cpp_bspline_arrives_intact_in_rospy(self):
        got = []
        event = threading.Event()

        def on_msg(msg):
            got.append(msg)
            event.set()

        rospy.Subscriber("bspline", Bspline, on_msg)
        self.assertTrue(event.wait(30.0), "no Bspline received from the C++ publisher within 30 s")
        msg = got[0]
        self.assertEqual(msg._md5sum, "b352d4f7278a546180de67cbe6793e49")
        self.assertEqual(msg.order, 3)
        self.assertEqual(msg.traj_id, 4242424242)
        self.assertEqual((msg.start_time.secs, msg.start_time.nsecs), (12, 345000000))
        self.assertEqual(list(msg.knots), [0.25 * i for i in range(7 + 3 + 1)])
        self.assertEqual(len(msg.pos_pts), 7)
        for i, p in enumerate(msg.pos_pts):
            self.assertEqual((p.x, p.y, p.z), (0.5 * i, -0.125 * i * i, 1.0 + 1e-9 * i))
        self.assertEqual(list(msg.yaw_pts), [0.1 * i for i in range(7)])
        self.assertEqual(msg.yaw_dt, 0.3)


if __name__ == "__main__":
    rospy.init_node("check_bspline_wire")
    rostest.rosrun("quad_il", "bspline_wire", BsplineWireTest)
