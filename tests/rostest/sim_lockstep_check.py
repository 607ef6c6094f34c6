#!/usr/bin/env python3
"""rostest node for quad_sim's lockstep mode: a scripted controller and depth consumer in one process.

Every odometry message is answered with an SO3Command stamped with its stamp (a PD loop on the odometry,
so the run is closed loop) and every depth frame with a FrameAck. Two episodes with the same seed must give
bit-identical odometry and depth streams even when the answers are delayed at random (as under CPU load).
"""

import hashlib
import math
import random
import struct
import threading
import time
import unittest

import rospy
import rostest
from geometry_msgs.msg import Point, Pose, Quaternion
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Image

from quad_msgs.msg import EpisodeStatus, FrameAck, SO3Command
from quad_msgs.srv import ResetEpisode, ResetEpisodeRequest

MASS_KG = 0.75
GRAVITY = 9.81
ODOM_PER_RUN = 400  # 2 s of sim time at 200 Hz


class Controller:
    """PD position loop on the SO(3) interface; the reference is a function of the episode-relative step."""

    def __init__(self, target_fn):
        self.target_fn = target_fn

    def command(self, odom: Odometry, k: int) -> SO3Command:
        p = odom.pose.pose.position
        v = odom.twist.twist.linear
        (tx, ty, tz), (vx_ref, vy_ref, vz_ref) = self.target_fn(k)
        ax = 6.0 * (tx - p.x) + 4.0 * (vx_ref - v.x)
        ay = 6.0 * (ty - p.y) + 4.0 * (vy_ref - v.y)
        az = 6.0 * (tz - p.z) + 4.0 * (vz_ref - v.z)
        cmd = SO3Command()
        cmd.header.stamp = odom.header.stamp
        cmd.force.x = MASS_KG * ax
        cmd.force.y = MASS_KG * ay
        cmd.force.z = MASS_KG * (az + GRAVITY)
        # Attitude tilted towards the desired acceleration (small angles, yaw 0): R = Ry(pitch) Rx(roll).
        roll = max(-0.3, min(0.3, -ay / GRAVITY))
        pitch = max(-0.3, min(0.3, ax / GRAVITY))
        cr, sr, cp, sp = math.cos(roll / 2), math.sin(roll / 2), math.cos(pitch / 2), math.sin(pitch / 2)
        cmd.orientation = Quaternion(x=sr * cp, y=cr * sp, z=-sr * sp, w=cr * cp)
        cmd.kR = [1.5, 1.5, 1.0]
        cmd.kOm = [0.13, 0.13, 0.1]
        cmd.aux.enable_motors = True
        return cmd


class LockstepTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("sim_lockstep_check")
        cls.lock = threading.Lock()
        cls.running = False
        cls.delays = None
        cls.controller = None
        cls.odom_log = []
        cls.depth_log = []
        cls.first_stamp = None
        cls.done = threading.Event()
        cls.status = None
        cls.status_event = threading.Event()
        cls.cmd_pub = rospy.Publisher("so3_cmd", SO3Command, queue_size=10, tcp_nodelay=True)
        cls.ack_pub = rospy.Publisher("sim/frame_ack", FrameAck, queue_size=10, tcp_nodelay=True)
        rospy.Subscriber("odom", Odometry, cls.on_odom, tcp_nodelay=True, queue_size=100)
        rospy.Subscriber("camera/depth/image", Image, cls.on_depth, tcp_nodelay=True, queue_size=10)
        rospy.Subscriber("sim/status", EpisodeStatus, cls.on_status)
        rospy.wait_for_service("sim/reset", timeout=60.0)
        cls.reset = rospy.ServiceProxy("sim/reset", ResetEpisode)

    @classmethod
    def maybe_delay(cls):
        if cls.delays is not None:
            time.sleep(cls.delays.uniform(0.0, 0.008))

    @classmethod
    def on_odom(cls, msg: Odometry):
        with cls.lock:
            if not cls.running:
                return
            if cls.first_stamp is None:
                cls.first_stamp = msg.header.stamp
            k = len(cls.odom_log)
            rel = (msg.header.stamp - cls.first_stamp).to_nsec()
            p, q, v, w = (
                msg.pose.pose.position,
                msg.pose.pose.orientation,
                msg.twist.twist.linear,
                msg.twist.twist.angular,
            )
            values = (p.x, p.y, p.z, q.x, q.y, q.z, q.w, v.x, v.y, v.z, w.x, w.y, w.z)
            cls.odom_log.append((rel, struct.pack("13d", *values)))
            if len(cls.odom_log) >= ODOM_PER_RUN:
                cls.running = False  # leave this odometry unanswered: the simulator holds time here
                cls.done.set()
                return
            cmd = cls.controller.command(msg, k)
        cls.maybe_delay()
        cls.cmd_pub.publish(cmd)

    @classmethod
    def on_depth(cls, msg: Image):
        with cls.lock:
            if not cls.running:
                return
            rel = (msg.header.stamp - cls.first_stamp).to_nsec() if cls.first_stamp is not None else -1
            cls.depth_log.append(
                (rel, msg.encoding, msg.width, msg.height, hashlib.sha256(msg.data).hexdigest())
            )
        cls.maybe_delay()
        cls.ack_pub.publish(
            FrameAck(consumer="test_consumer", frame_seq=msg.header.seq, stamp=msg.header.stamp)
        )

    @classmethod
    def on_status(cls, msg: EpisodeStatus):
        with cls.lock:
            cls.status = msg
        cls.status_event.set()

    def fly(self, seed, delays, target_fn, world_file="", start=None, goal=(18.0, 0.0, 1.5)):
        cls = type(self)
        with cls.lock:
            cls.odom_log, cls.depth_log, cls.first_stamp = [], [], None
            cls.delays = delays
            cls.controller = Controller(target_fn)
            cls.done.clear()
            cls.running = True
        req = ResetEpisodeRequest(seed=seed, world_file=world_file)
        if start is not None:
            req.start = Pose(position=Point(*start), orientation=Quaternion(0, 0, 0, 1))
            req.goal = Point(*goal)
        res = cls.reset(req)
        self.assertTrue(res.success, res.message)
        self.assertTrue(cls.done.wait(120.0), "episode did not produce %d odometry messages" % ODOM_PER_RUN)
        with cls.lock:
            return list(cls.odom_log), list(cls.depth_log), res.episode_id

    def test_a_two_runs_with_the_same_seed_are_bit_identical(self):
        # Take off from the configured start (on the ground) and drift sideways: closed loop on the odometry.
        def target(k):
            t = k * 0.005
            return (-18.0 + 0.3 * t, 0.2 * t, min(1.5, 0.2 + 1.0 * t)), (0.3, 0.2, 1.0 if t < 1.3 else 0.0)

        odom1, depth1, ep1 = self.fly(seed=3, delays=None, target_fn=target)
        odom2, depth2, ep2 = self.fly(seed=3, delays=random.Random(5), target_fn=target)
        self.assertEqual(ep2, ep1 + 1)
        self.assertEqual(len(odom1), ODOM_PER_RUN)
        # Lockstep: consecutive odometry exactly one control period apart, depth frames at k/30 s.
        self.assertEqual([r for r, _ in odom1], [5_000_000 * i for i in range(ODOM_PER_RUN)])
        self.assertEqual(len(depth1), 60)
        self.assertEqual(
            [d[0] for d in depth1], [math.ceil(k * 100.0 / 3.0 - 1e-9) * 1_000_000 for k in range(60)]
        )
        self.assertEqual(odom1, odom2, "odometry streams differ between the two runs")
        self.assertEqual(depth1, depth2, "depth streams differ between the two runs")
        # The vehicle really flew: it climbed from the ground.
        z_end = struct.unpack("13d", odom1[-1][1])[2]
        self.assertGreater(z_end, 1.0)
        # Every lockstep timeout republishes the status with a count in its reason: there must be none.
        with type(self).lock:
            status = type(self).status
        self.assertIsNotNone(status)
        self.assertEqual(status.episode_id, ep2)
        self.assertNotIn("lockstep timeouts", status.reason)

    def test_b_flying_into_a_pillar_is_reported_on_the_status_topic(self):
        gate = rospy.get_param("~gate_world")

        # From (2, -1.5, 1.5) towards +x at 2 m/s: the pillar at (5, -1.5) has its face at x = 4.75.
        def target(k):
            t = k * 0.005
            return (2.0 + 2.0 * t, -1.5, 1.5), (2.0, 0.0, 0.0)

        cls = type(self)
        cls.status_event.clear()
        self.fly(seed=0, delays=None, target_fn=target, world_file=gate, start=(2.0, -1.5, 1.5))
        # Wall-clock waits: sim time stands still while this node holds the lockstep.
        deadline = time.monotonic() + 10.0
        while not rospy.is_shutdown():
            with cls.lock:
                st = cls.status
            if st is not None and st.collided:
                break
            self.assertLess(time.monotonic(), deadline, "no collision on /sim/status")
            time.sleep(0.05)
        self.assertEqual(st.collision_box_id, 0)
        self.assertFalse(st.active)
        self.assertIn("collision with box 0", st.reason)
        self.assertAlmostEqual(st.collision_point.x, 4.75, delta=0.02)
        self.assertAlmostEqual(st.collision_point.y, -1.5, delta=0.3)


if __name__ == "__main__":
    rostest.rosrun("quad_il", "sim_lockstep", LockstepTest)
