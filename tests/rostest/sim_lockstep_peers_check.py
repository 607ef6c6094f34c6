#!/usr/bin/env python3
"""rostest node of sim_lockstep_peers.test: the start-up race behind issue 30's 20 s stalls, made
deterministic.

The node is the command source and the depth consumer `test_consumer` of sim_lockstep.yaml. It registers its
odometry subscription with the master first, without connecting it (what a node's subscription looks like
while its connection is still being set up), then connects everything else. Counting connections, the
simulator started stepping now (rostopic already takes odometry): the first odometry went to nobody here, and
the evaluation's expert planner, which waits for a frame's odometry, left the first frame unacknowledged for
the whole lockstep timeout. The simulator must instead say that it waits for this node's odometry connection,
publish no clock until it is connected, and then step with every wait answered in time.
"""

import threading
import unittest

import rosgraph
import rospy
import rostest
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock, Log
from sensor_msgs.msg import Image

from quad_msgs.msg import FrameAck, SimStats, SO3Command

FIRST_STAMP_NS = 1_005_000_000  # quad_sim's time base (1 s) plus one odometry period at 200 Hz
ODOM_WANTED = 100  # 0.5 s of sim time
MASS_KG = 0.75
GRAVITY = 9.81
WAIT_S = 30.0


class PeerBarrierTest(unittest.TestCase):
    def test_no_step_before_a_consumers_registered_odometry_is_connected(self) -> None:
        rospy.init_node("sim_lockstep_peers_check")
        me = rospy.get_name()
        cv = threading.Condition()
        state = {"clock_ns": [], "odom_ns": [], "waiting_log": "", "stats": None}
        # 1. Registered, not connected: the master lists this node as an odometry subscriber.
        rosgraph.Master(me).registerSubscriber("/odom", "nav_msgs/Odometry", rospy.get_node_uri())

        cmd_pub = rospy.Publisher("so3_cmd", SO3Command, queue_size=10, tcp_nodelay=True)
        ack_pub = rospy.Publisher("sim/frame_ack", FrameAck, queue_size=10, tcp_nodelay=True)

        def on_depth(msg: Image) -> None:
            h = msg.header
            ack_pub.publish(FrameAck(consumer="test_consumer", frame_seq=h.seq, stamp=h.stamp))

        def on_clock(msg: Clock) -> None:
            with cv:
                state["clock_ns"].append(msg.clock.to_nsec())
                cv.notify_all()

        def on_log(msg: Log) -> None:
            if msg.name == "/quad_sim" and f"{me} registered for /odom but not yet connected" in msg.msg:
                with cv:
                    state["waiting_log"] = msg.msg
                    cv.notify_all()

        def on_odom(msg: Odometry) -> None:
            with cv:
                state["odom_ns"].append(msg.header.stamp.to_nsec())
                cv.notify_all()
            cmd = SO3Command()  # hover thrust on the ground: the vehicle stays put
            cmd.header.stamp = msg.header.stamp
            cmd.force.z = MASS_KG * GRAVITY
            cmd.orientation.w = 1.0
            cmd.aux.enable_motors = True
            cmd_pub.publish(cmd)

        def on_stats(msg: SimStats) -> None:
            with cv:
                state["stats"] = msg
                cv.notify_all()

        rospy.Subscriber("/rosout", Log, on_log, queue_size=100)
        rospy.Subscriber("sim/stats", SimStats, on_stats, queue_size=100)
        rospy.Subscriber("camera/depth/image", Image, on_depth, tcp_nodelay=True, queue_size=10)
        rospy.Subscriber("/clock", Clock, on_clock, queue_size=100)

        # 2. The simulator says it waits for exactly that subscription (it logs what it waits for every 5 s).
        with cv:
            self.assertTrue(
                cv.wait_for(lambda: state["waiting_log"], WAIT_S),
                f"quad_sim never said it waits for {me}'s odometry connection",
            )
            # It has not stepped: no clock yet (its first clock goes out with the first odometry).
            self.assertEqual(state["clock_ns"], [], "quad_sim stepped before our odometry was connected")

        # 3. Connect it: the simulator starts, and the first odometry reaches this node.
        rospy.Subscriber("odom", Odometry, on_odom, tcp_nodelay=True, queue_size=100)
        with cv:
            self.assertTrue(
                cv.wait_for(lambda: len(state["odom_ns"]) >= ODOM_WANTED, WAIT_S),
                f"fewer than {ODOM_WANTED} odometry messages",
            )
            got = list(state["odom_ns"])
        self.assertEqual(got[0], FIRST_STAMP_NS, f"first odometry stamped {got[0] * 1e-9:.3f} s, not 1.005 s")
        self.assertTrue(all(b - a == 5_000_000 for a, b in zip(got, got[1:], strict=False)), got[:20])
        # 4. No lockstep wait timed out (the simulator's statistics before a later frame say so).
        with cv:
            self.assertTrue(
                cv.wait_for(lambda: state["stats"] and state["stats"].depth_frame_count > 3, WAIT_S),
                "no simulator statistics",
            )
            stats = state["stats"]
        self.assertEqual(stats.lockstep_command_timeouts, 0)
        self.assertEqual(stats.lockstep_ack_timeouts, 0)


if __name__ == "__main__":
    rostest.rosrun("quad_il", "sim_lockstep_peers", PeerBarrierTest)
