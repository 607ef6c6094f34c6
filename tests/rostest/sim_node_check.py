#!/usr/bin/env python3
"""rostest node for quad_sim_node: topics and rates, latched data, set_z_offset, bad input, reset.

Every wait ends on its condition (a message, a sim-time stamp); the wall-time limits are failure guards."""

import math
import threading
import time
import unittest

import numpy as np
import rospy
import rostest
import tf2_ros
from geometry_msgs.msg import Point, Pose, Quaternion
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from std_msgs.msg import Float64
from visualization_msgs.msg import MarkerArray

from quad_msgs.msg import EpisodeStatus, SimStats, SO3Command
from quad_msgs.srv import ResetEpisode, ResetEpisodeRequest


def wait_until(pred, timeout_s: float, what: str) -> None:
    """Polls a condition; timeout_s (wall time) is a failure guard (sim time runs at the simulator's pace)."""
    deadline = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > deadline:
            raise AssertionError("timed out waiting for " + what)
        time.sleep(0.02)


class SimNodeTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("sim_node_check")
        cls.lock = threading.Lock()
        cls.odom, cls.images, cls.infos, cls.logs = [], [], [], []
        cls.latched = {}
        cls.stats = None
        subs = [
            ("odom", Odometry, lambda m: cls.append("odom", m)),
            ("camera/depth/image", Image, lambda m: cls.append("images", m)),
            ("camera/depth/camera_info", CameraInfo, lambda m: cls.append("infos", m)),
            ("/rosout", Log, lambda m: cls.append("logs", m)),
            ("sim/world_markers", MarkerArray, lambda m: cls.latch("markers", m)),
            ("sim/voxel_map", PointCloud2, lambda m: cls.latch("voxels", m)),
            ("sim/z_offset", Float64, lambda m: cls.latch("z_offset", m)),
            ("sim/status", EpisodeStatus, lambda m: cls.latch("status", m)),
            ("sim/stats", SimStats, lambda m: cls.latch("stats", m)),
        ]
        for topic, typ, cb in subs:
            rospy.Subscriber(topic, typ, cb, queue_size=1000)
        cls.cmd_pub = rospy.Publisher("so3_cmd", SO3Command, queue_size=10)
        rospy.wait_for_service("sim/reset", timeout=60.0)
        cls.reset = rospy.ServiceProxy("sim/reset", ResetEpisode)
        names = ("markers", "voxels", "z_offset", "status")
        wait_until(lambda: all(k in cls.latched for k in names), 30, "latched topics")

    @classmethod
    def append(cls, name, msg):
        with cls.lock:
            getattr(cls, name).append(msg)

    @classmethod
    def latch(cls, name, msg):
        with cls.lock:
            cls.latched[name] = msg

    def snapshot(self, name):
        with self.lock:
            return list(getattr(self, name))

    def test_odometry_at_200hz_and_depth_at_30hz_of_sim_time(self):
        def enough():
            return len(self.snapshot("odom")) > 400 and len(self.snapshot("images")) > 60

        wait_until(enough, 60, "2 s of messages")
        odom = self.snapshot("odom")
        stamps = np.array([m.header.stamp.to_nsec() for m in odom[-400:]])
        self.assertTrue(np.all(np.diff(stamps) == 5_000_000), "odometry not every 5 ms of sim time")
        self.assertEqual(odom[-1].header.frame_id, "world")
        self.assertEqual(odom[-1].child_frame_id, "base_link")
        images = self.snapshot("images")[-60:]
        gaps = set(np.diff([m.header.stamp.to_nsec() for m in images]).tolist())
        self.assertTrue(gaps <= {33_000_000, 34_000_000}, gaps)
        img = images[-1]
        self.assertEqual((img.encoding, img.width, img.height, img.step), ("32FC1", 320, 240, 1280))
        self.assertEqual(img.header.frame_id, "camera")
        depth = np.frombuffer(img.data, dtype=np.float32).reshape(240, 320)
        # REP 118: finite metres or +-Inf, no NaN; the ground fills the lower rows.
        self.assertFalse(np.isnan(depth).any())
        self.assertTrue(np.isfinite(depth[-1]).all())
        info = self.snapshot("infos")[-1]
        self.assertAlmostEqual(info.K[0], 193.6)
        self.assertAlmostEqual(info.K[4], 193.6)
        self.assertAlmostEqual(info.K[2], 159.5)
        self.assertEqual(info.header.stamp, self.snapshot("infos")[-1].header.stamp)

    def test_latched_world_and_voxel_map(self):
        with self.lock:
            markers = self.latched["markers"].markers
            cloud = self.latched["voxels"]
        boxes = [m for m in markers if m.ns == "boxes"]
        self.assertEqual(len(boxes), 200)
        self.assertEqual({m.ns for m in markers if m.action == 0}, {"boxes", "ground", "goal", "vehicle"})
        self.assertEqual(cloud.header.frame_id, "world")
        self.assertGreater(cloud.width, 100_000)
        pts = np.frombuffer(cloud.data, dtype=np.float32).reshape(-1, cloud.point_step // 4)[:, :3]
        # Voxel centres on the OctoMap grid: (k + 1/2) * 0.1 m.
        frac = np.abs(pts / 0.1 - 0.5 - np.round(pts / 0.1 - 0.5))
        self.assertLess(float(frac.max()), 1e-3)

    def test_set_z_offset_is_measured_and_odometry_is_in_the_world_frame(self):
        with self.lock:
            z_offset = self.latched["z_offset"].data
        # The engine's spawn frame is 1.7 m above the ground (sim_node.yaml, centimetres).
        self.assertAlmostEqual(z_offset, 1.7, places=9)
        wait_until(lambda: len(self.snapshot("odom")) > 10, 30, "odometry")
        p = self.snapshot("odom")[-1].pose.pose.position
        # Resting on the ground at the configured start: z = half box height minus a sub-millimetre sink.
        self.assertAlmostEqual(p.x, -18.0, delta=1e-3)
        self.assertAlmostEqual(p.y, 0.0, delta=1e-3)
        self.assertAlmostEqual(p.z, 0.125, delta=1e-3)

    def test_tf_gives_the_camera_mount(self):
        buf = tf2_ros.Buffer()
        tf2_ros.TransformListener(buf)
        wait_until(lambda: buf.can_transform("base_link", "camera", rospy.Time(0)), 30, "base_link->camera")
        t = buf.lookup_transform("base_link", "camera", rospy.Time(0)).transform
        self.assertAlmostEqual(t.translation.x, 0.1)
        # Optical frame: its z axis is base_link's x axis.
        q = t.rotation
        z_axis_x = 2.0 * (q.x * q.z + q.w * q.y)
        self.assertAlmostEqual(z_axis_x, 1.0, places=6)
        wait_until(lambda: buf.can_transform("world", "camera", rospy.Time(0)), 30, "world->camera")

    def test_nan_command_is_rejected_with_a_log_line(self):
        wait_until(lambda: self.cmd_pub.get_num_connections() > 0, 30, "the simulator to subscribe so3_cmd")
        cmd = SO3Command()
        cmd.force.z = math.nan
        cmd.orientation.w = 1.0
        cmd.aux.enable_motors = True

        def logged():
            return any("rejected SO3Command" in m.msg and "NaN/Inf" in m.msg for m in self.snapshot("logs"))

        def sent_and_logged():
            # Sent again at each poll until the rejection is logged: a message published while the
            # connection is still being set up can be lost.
            if logged():
                return True
            self.cmd_pub.publish(cmd)
            return False

        wait_until(sent_and_logged, 30, "the rejection log line")

        def counted():
            with self.lock:
                return "stats" in self.latched and self.latched["stats"].rejected_commands >= 1

        wait_until(counted, 30, "the rejection in /sim/stats")
        # Half a second of sim time after the rejection was counted, the vehicle is still resting on the
        # ground, motionless: the NaN never reached it (the bit-exact "state untouched" check is the gtest
        # Commands.NanOrInfCommandIsRejectedAndLeavesStateUntouched).
        with self.lock:
            after_ns = self.latched["stats"].header.stamp.to_nsec() + 500_000_000
        wait_until(
            lambda: self.snapshot("odom")[-1].header.stamp.to_nsec() >= after_ns,
            30,
            "odometry 0.5 s of sim time after the rejection",
        )
        odom = self.snapshot("odom")[-1]
        self.assertAlmostEqual(odom.pose.pose.position.z, 0.125, delta=1e-3)
        v = odom.twist.twist.linear
        self.assertLess(math.sqrt(v.x**2 + v.y**2 + v.z**2), 1e-3)

    def test_zz_reset_errors_and_a_new_episode(self):
        gate = rospy.get_param("~gate_world")
        req = ResetEpisodeRequest(seed=0, world_file=gate)
        # Inside pillar 0 of the gate world.
        req.start = Pose(position=Point(5.0, -1.5, 1.5), orientation=Quaternion(0, 0, 0, 1))
        req.goal = Point(12.0, 0.0, 1.5)
        res = self.reset(req)
        self.assertFalse(res.success)
        self.assertIn("inside world box 0", res.message)
        req.world_file = "/nonexistent/world.yaml"
        res = self.reset(req)
        self.assertFalse(res.success)
        self.assertIn("cannot open", res.message)
        with self.lock:
            episode_before = self.latched["status"].episode_id
        req.world_file = gate
        req.start.position = Point(0.0, 0.0, 1.0)
        res = self.reset(req)
        self.assertTrue(res.success, res.message)
        self.assertEqual(res.episode_id, episode_before + 1)

        def gate_markers():
            return len([m for m in self.latched["markers"].markers if m.ns == "boxes"]) == 4

        wait_until(gate_markers, 30, "the gate world's markers")
        wait_until(lambda: self.latched["status"].episode_id == res.episode_id, 30, "new status")
        with self.lock:
            status = self.latched["status"]
        self.assertAlmostEqual(status.goal.x, 12.0)
        self.assertEqual(status.world_seed, 0)


if __name__ == "__main__":
    rostest.rosrun("quad_il", "sim_node", SimNodeTest)
