#!/usr/bin/env python3
"""rostest node of sim_lockstep_startup.test: a command source whose odometry subscription connects late.

The node publishes commands and acknowledges depth frames from the start (so quad_sim's peer check passes
together with the early odometry listener of the launch file), waits until the simulator has published its
first odometry (the base_link transform the simulator broadcasts right after it has that stamp) and only then
subscribes to odometry. ROS drops messages published before a subscriber connects, so without the simulator's
resend the first odometry would never arrive: the simulator would stall for lockstep.timeout_s (10 s in
sim_lockstep.yaml), count a command timeout and step on, and the first odometry received would be the second.
Every wait ends on its condition; the wall-time limits are failure guards only.
"""

import threading
import unittest

import rospy
import rostest
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Image
from tf2_msgs.msg import TFMessage

from quad_msgs.msg import FrameAck, SimStats, SO3Command

FIRST_STAMP_NS = 1_005_000_000  # quad_sim's time base (1 s) plus one odometry period at 200 Hz
ODOM_WANTED = 100  # 0.5 s of sim time
MASS_KG = 0.75
GRAVITY = 9.81
GUARD_S = 60.0  # wall-time failure guard of every wait


class LateSubscriberTest(unittest.TestCase):
    def test_first_odometry_is_sent_again_until_answered(self) -> None:
        rospy.init_node("sim_lockstep_startup_check")
        lock = threading.Lock()
        stamps: list[int] = []
        first_rx = threading.Event()
        enough = threading.Event()
        first_out = threading.Event()
        stats: list[SimStats] = []
        stats_cv = threading.Condition(lock)
        cmd_pub = rospy.Publisher("so3_cmd", SO3Command, queue_size=10, tcp_nodelay=True)
        ack_pub = rospy.Publisher("sim/frame_ack", FrameAck, queue_size=10, tcp_nodelay=True)

        def on_depth(msg: Image) -> None:
            ack = FrameAck(consumer="test_consumer", frame_seq=msg.header.seq, stamp=msg.header.stamp)
            ack_pub.publish(ack)

        def on_tf(msg: TFMessage) -> None:
            # The simulator broadcasts the vehicle's transform right after publishing the odometry of the
            # same stamp.
            if any(
                t.child_frame_id == "base_link" and t.header.stamp.to_nsec() >= FIRST_STAMP_NS
                for t in msg.transforms
            ):
                first_out.set()

        def on_stats(msg: SimStats) -> None:
            with stats_cv:
                stats.append(msg)
                stats_cv.notify_all()

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
        rospy.Subscriber("/tf", TFMessage, on_tf, queue_size=100)
        rospy.Subscriber("sim/stats", SimStats, on_stats, queue_size=10)
        self.assertTrue(first_out.wait(GUARD_S), "quad_sim never published its first odometry")
        # The first odometry is out and unanswered (nobody sends its command yet): the simulator waits on it.
        rospy.Subscriber("odom", Odometry, on_odom, tcp_nodelay=True, queue_size=100)
        self.assertTrue(first_rx.wait(GUARD_S), "no odometry after subscribing")
        self.assertTrue(enough.wait(GUARD_S), f"fewer than {ODOM_WANTED} odometry messages")
        with lock:
            got = list(stamps)
        # The first odometry arrives (sent again), not released by the lockstep timeout: the first stamp
        # received is the first one, and the simulator counted no command timeout up to the stamps received.
        self.assertEqual(got[0], FIRST_STAMP_NS, f"first odometry stamped {got[0] * 1e-9:.3f} s, not 1.005 s")
        with stats_cv:
            self.assertTrue(
                stats_cv.wait_for(lambda: any(m.header.stamp.to_nsec() >= got[-1] for m in stats), GUARD_S),
                "no /sim/stats after the odometry received",
            )
            last = next(m for m in stats if m.header.stamp.to_nsec() >= got[-1])
        self.assertEqual(last.lockstep_command_timeouts, 0, "the first odometry was released by a timeout")
        # Then the ordinary lockstep stream: every later stamp one period after the one before, none skipped
        # (resends of the first stamp before our first answer got through may repeat it).
        later = [s for s in got if s != FIRST_STAMP_NS]
        self.assertEqual(later[0], FIRST_STAMP_NS + 5_000_000)
        self.assertTrue(all(b - a == 5_000_000 for a, b in zip(later, later[1:], strict=False)), later[:20])


if __name__ == "__main__":
    rostest.rosrun("quad_il", "sim_lockstep_startup", LateSubscriberTest)
