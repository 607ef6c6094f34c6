#!/usr/bin/env python3
"""rostest node of sim_lockstep_startup.test: a command source whose odometry subscription connects late.

The node publishes commands and acknowledges depth frames from the start (so quad_sim's peer check passes
together with the early odometry listener of the launch file), waits until the simulator has published its
first odometry (its /clock reached that stamp) and only then subscribes to odometry. ROS drops messages
published before a subscriber connects, so without the simulator's resend the first odometry would never
arrive and the simulator would stall for lockstep.timeout_s (10 s in sim_lockstep.yaml).
"""

import threading
import time
import unittest

import rospy
import rostest
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Image

from quad_msgs.msg import FrameAck, SO3Command

FIRST_STAMP_NS = 1_005_000_000  # quad_sim's time base (1 s) plus one odometry period at 200 Hz
ODOM_WANTED = 100  # 0.5 s of sim time
MASS_KG = 0.75
GRAVITY = 9.81


class LateSubscriberTest(unittest.TestCase):
    def test_first_odometry_is_sent_again_until_answered(self) -> None:
        rospy.init_node("sim_lockstep_startup_check")
        lock = threading.Lock()
        stamps: list[int] = []
        first_rx = threading.Event()
        enough = threading.Event()
        clock_seen = threading.Event()
        cmd_pub = rospy.Publisher("so3_cmd", SO3Command, queue_size=10, tcp_nodelay=True)
        ack_pub = rospy.Publisher("sim/frame_ack", FrameAck, queue_size=10, tcp_nodelay=True)

        def on_depth(msg: Image) -> None:
            ack = FrameAck(consumer="test_consumer", frame_seq=msg.header.seq, stamp=msg.header.stamp)
            ack_pub.publish(ack)

        def on_clock(msg: Clock) -> None:
            if msg.clock.to_nsec() >= FIRST_STAMP_NS:
                clock_seen.set()

        def on_odom(msg: Odometry) -> None:
            with lock:
                stamps.append(msg.header.stamp.to_nsec())
                n = len(stamps)
            first_rx.set()
            if n >= ODOM_WANTED:
                enough.set()
            cmd = SO3Command()  # hover thrust on the ground: the vehicle stays put
            cmd.header.stamp = msg.header.stamp
            cmd.force.z = MASS_KG * GRAVITY
            cmd.orientation.w = 1.0
            cmd.aux.enable_motors = True
            cmd_pub.publish(cmd)

        rospy.Subscriber("camera/depth/image", Image, on_depth, tcp_nodelay=True, queue_size=10)
        rospy.Subscriber("/clock", Clock, on_clock, queue_size=10)
        self.assertTrue(clock_seen.wait(60.0), "quad_sim never reached its first odometry stamp")
        time.sleep(1.0)  # the first odometry is out and unanswered: the simulator waits on it
        subscribed = time.monotonic()
        rospy.Subscriber("odom", Odometry, on_odom, tcp_nodelay=True, queue_size=100)
        self.assertTrue(first_rx.wait(8.0), "no odometry within 8 s of subscribing")
        first_delay = time.monotonic() - subscribed
        self.assertTrue(enough.wait(20.0), f"fewer than {ODOM_WANTED} odometry messages")
        with lock:
            got = list(stamps)
        # The first odometry arrives (sent again), well before the 10 s lockstep timeout would release it.
        self.assertEqual(got[0], FIRST_STAMP_NS, f"first odometry stamped {got[0] * 1e-9:.3f} s, not 1.005 s")
        self.assertLess(first_delay, 5.0)
        # Then the ordinary lockstep stream: every later stamp one period after the one before, none skipped
        # (resends of the first stamp before our first answer got through may repeat it).
        later = [s for s in got if s != FIRST_STAMP_NS]
        self.assertEqual(later[0], FIRST_STAMP_NS + 5_000_000)
        self.assertTrue(all(b - a == 5_000_000 for a, b in zip(later, later[1:], strict=False)), later[:20])


if __name__ == "__main__":
    rostest.rosrun("quad_il", "sim_lockstep_startup", LateSubscriberTest)
