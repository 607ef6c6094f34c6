#!/usr/bin/env python3
"""rostest node: the C++ node (quad_policy/policy_node, namespace /cpp) and the Python node (quad_il
policy_node.py, namespace /py) are fed the same recorded inputs as ROS messages (odometry, camera info, goal,
32FC1 depth frames, the camera's static transform) and must publish the same decisions and the same B-splines
(control points within 1e-4), acknowledge every frame, and skip the same frames for the same reasons (no goal
yet, a depth frame of the wrong encoding). No simulator and no tracker: the nodes only publish
(~send_to_tracker false), at a replanning rate of half the frame rate. The policy is a seeded random-init
export with local state and output frames. Every wait ends on its condition (connections, the goal's answer,
each frame's acknowledgement; the nodes wait for each frame's odometry, ~odom_wait_s); the wall-time limits
are failure guards only."""

from __future__ import annotations

import math
import shutil
import tempfile
import threading
import time
import unittest
from collections import defaultdict
from pathlib import Path

import numpy as np
import rospy
import rostest
import yaml
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from policy_nodes_common import NAMESPACES, broadcast_camera_mount, policy_nodes
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import String

from quad_il.inference.random_policy import export_random_policy
from quad_il.learning.config import ModelConfig
from quad_il.learning.synthetic import make_synthetic_arrays
from quad_msgs.msg import Bspline, FrameAck, PolicyDecision

GUARD_S = 60.0  # wall-time failure guard of every wait
H, W = 60, 80
K = np.array([387.2 * W / 640, 0, (W - 1) / 2, 0, 387.2 * H / 480, (H - 1) / 2, 0, 0, 1])


def exact_time(t: float) -> rospy.Time:
    """The nearest nanosecond (rospy.Time.from_sec truncates: from_sec(2.4) is 2.399999999 s)."""
    secs = math.floor(t)
    nsecs = round((t - secs) * 1e9)
    return rospy.Time(secs + nsecs // 1_000_000_000, nsecs % 1_000_000_000)


def key(stamp: rospy.Time) -> float:
    """Frames are matched by stamp, rounded to the microsecond."""
    return round(stamp.to_sec(), 6)


class NodeOutputs:
    """Everything one namespace's node publishes, keyed by the depth frame's stamp."""

    def __init__(self, ns: str) -> None:
        self.lock = threading.Lock()
        self.decisions: dict[float, PolicyDecision] = {}
        self.bsplines: dict[int, Bspline] = {}
        self.acks: dict[float, FrameAck] = {}
        self.status: list[str] = []
        rospy.Subscriber(f"/{ns}/policy/status", String, self._on_status, queue_size=10)
        rospy.Subscriber(f"/{ns}/policy/decision", PolicyDecision, self._on_decision, queue_size=100)
        rospy.Subscriber(f"/{ns}/planner/bspline", Bspline, self._on_bspline, queue_size=100)
        rospy.Subscriber(f"/{ns}/sim/frame_ack", FrameAck, self._on_ack, queue_size=100)

    def _on_status(self, m: String) -> None:
        with self.lock:
            self.status.append(m.data)

    def _on_decision(self, m: PolicyDecision) -> None:
        with self.lock:
            self.decisions[key(m.header.stamp)] = m

    def _on_bspline(self, m: Bspline) -> None:
        with self.lock:
            self.bsplines[m.traj_id] = m

    def _on_ack(self, m: FrameAck) -> None:
        with self.lock:
            self.acks[key(m.stamp)] = m


def depth_message(depth: np.ndarray, stamp: rospy.Time, encoding: str = "32FC1") -> Image:
    m = Image()
    m.header.stamp = stamp
    m.header.frame_id = "camera"
    m.height, m.width = depth.shape
    m.encoding = encoding
    m.is_bigendian = 0
    m.step = 4 * depth.shape[1]
    m.data = np.ascontiguousarray(depth, dtype="<f4").tobytes()
    return m


class InferNodeParity(unittest.TestCase):
    def test_cpp_and_python_nodes_publish_the_same_decisions(self) -> None:
        work = Path(tempfile.mkdtemp(prefix="infer_node_parity_"))
        self.addCleanup(shutil.rmtree, work, True)
        model = ModelConfig(input_height=32, input_width=32, state_frame="local", output_frame="local")
        policy = export_random_policy(work / "policy.ts", model, seed=3)
        # The repository config with a replanning rate: frames come 0.1 s apart, every other one is decided.
        cfg = yaml.safe_load(Path(rospy.get_param("~policy_config")).read_text())
        cfg["replan_rate_hz"] = 5.0
        # A frame waits for its own odometry (published just before it, on another topic) as long as it
        # takes: the guard only.
        cfg["odom_wait_s"] = GUARD_S
        config_path = work / "policy.yaml"
        config_path.write_text(yaml.safe_dump(cfg))
        outputs = {ns: NodeOutputs(ns) for ns in NAMESPACES}
        pubs = defaultdict(dict)
        for ns in NAMESPACES:
            pubs[ns]["odom"] = rospy.Publisher(f"/{ns}/odom", Odometry, queue_size=100, tcp_nodelay=True)
            pubs[ns]["depth"] = rospy.Publisher(f"/{ns}/camera/depth/image", Image, queue_size=100)
            pubs[ns]["info"] = rospy.Publisher(
                f"/{ns}/camera/depth/camera_info", CameraInfo, queue_size=1, latch=True
            )
            pubs[ns]["goal"] = rospy.Publisher(f"/{ns}/planner/goal", PoseStamped, queue_size=1, latch=True)
        self.tf = broadcast_camera_mount()
        params = {
            "config": str(config_path),
            "policy_file": str(policy),
            "send_to_tracker": False,
        }
        with policy_nodes(params) as procs:
            self._feed_and_compare(outputs, pubs)
            for p in procs:
                self.assertTrue(p.is_alive(), f"{p.name} died")

    def _wait_until(self, predicate, what: str) -> None:
        deadline = time.monotonic() + GUARD_S
        while not predicate():
            if time.monotonic() > deadline:
                self.fail(f"no {what} within {GUARD_S:g} s")
            time.sleep(0.01)

    def _wait_connected(self, pubs) -> None:
        # Both nodes subscribe to every input, including the camera's (latched) static transform, which
        # rospy writes to a subscriber as soon as it connects.
        self._wait_until(
            lambda: all(
                p[name].get_num_connections() > 0
                for p in pubs.values()
                for name in ("depth", "odom", "info", "goal")
            )
            and self.tf.pub_tf.get_num_connections() >= len(pubs),
            "subscriptions of both policy nodes",
        )

    def _send_frame(
        self, outputs, pubs, depth: np.ndarray, stamp: float, odom: Odometry | None, encoding: str = "32FC1"
    ) -> None:
        s = exact_time(stamp)
        # The nodes pair the frame with the newest odometry <= its stamp, waiting for it if it comes later.
        for ns in NAMESPACES:
            if odom is not None:
                pubs[ns]["odom"].publish(odom)
        for ns in NAMESPACES:
            pubs[ns]["depth"].publish(depth_message(depth, s, encoding))
        self._wait_until(
            lambda: all(stamp in o.acks and stamp in o.decisions for o in outputs.values()),
            f"decision and acknowledgement of frame {stamp} from both nodes",
        )

    def _feed_and_compare(self, outputs, pubs) -> None:
        self._wait_connected(pubs)
        a = make_synthetic_arrays(num_episodes=2, samples_per_episode=5, height=H, width=W, seed=11)
        depth = a["depth_m"].astype(np.float32)
        rng = np.random.default_rng(0)
        depth[rng.random(depth.shape) < 0.02] = -np.inf
        info = CameraInfo()
        info.header.frame_id = "camera"
        info.height, info.width = H, W
        info.K = K.tolist()
        for ns in NAMESPACES:
            pubs[ns]["info"].publish(info)

        def odom(i: int, stamp: float) -> Odometry:
            m = Odometry()
            m.header.stamp = exact_time(stamp)
            m.header.frame_id, m.child_frame_id = "world", "base_link"
            m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z = a["p_world_body"][
                i
            ].tolist()
            q = a["q_world_body"][i].astype(float)
            o = m.pose.pose.orientation
            o.x, o.y, o.z, o.w = q.tolist()
            m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z = a["v_world"][i].tolist()
            return m

        # Before any goal: both skip with no_goal (and acknowledge).
        self._send_frame(outputs, pubs, depth[0], 1.0, odom(0, 0.998))
        goal = PoseStamped()
        goal.header.frame_id = "world"
        goal.pose.position.x, goal.pose.position.y, goal.pose.position.z = a["goal_world"][0].tolist()
        goal.pose.orientation.w = 1.0
        for ns in NAMESPACES:
            pubs[ns]["goal"].publish(goal)
        self._wait_until(
            lambda: all(any(s.startswith("goal accepted") for s in o.status) for o in outputs.values()),
            "goal answer from both nodes",
        )
        stamps = [1.0]
        for i in range(len(depth)):
            stamp = round(2.0 + 0.1 * i, 6)
            self._send_frame(outputs, pubs, depth[i], stamp, odom(i, stamp - 0.002))
            stamps.append(stamp)
        # A frame of the wrong encoding: skipped by both, still acknowledged.
        self._send_frame(outputs, pubs, depth[0], 9.0, None, encoding="16UC1")
        stamps.append(9.0)

        # Each decision's B-spline travels on its own topic: wait for all of them.
        def all_bsplines() -> bool:
            for o in outputs.values():
                with o.lock:
                    if any(d.traj_id and d.traj_id not in o.bsplines for d in o.decisions.values()):
                        return False
            return True

        self._wait_until(all_bsplines, "B-splines of all decisions")

        cpp, py = outputs["cpp"], outputs["py"]
        statuses = []
        for s in stamps:
            dc, dp = cpp.decisions[s], py.decisions[s]
            statuses.append(dc.status)
            self.assertEqual(
                (dc.status, dc.verdict, dc.accepted, dc.action),
                (dp.status, dp.verdict, dp.accepted, dp.action),
                f"frame {s}",
            )
            self.assertEqual((dc.node, dp.node), ("cpp", "py"))
            for o in (cpp, py):
                self.assertEqual(o.acks[s].consumer, "policy")
            if dc.traj_id:
                bc, bp = cpp.bsplines[dc.traj_id], py.bsplines[dp.traj_id]
                self.assertEqual(bc.start_time, bp.start_time)
                self.assertEqual(key(bc.start_time), s)
                np.testing.assert_allclose(bc.knots, bp.knots, rtol=0, atol=1e-12)
                pc = np.array([[p.x, p.y, p.z] for p in bc.pos_pts])
                pp = np.array([[p.x, p.y, p.z] for p in bp.pos_pts])
                np.testing.assert_allclose(pc, pp, rtol=0, atol=1e-4, err_msg=f"frame {s}")
        self.assertEqual(statuses[0], "no_goal")
        self.assertEqual(statuses[-1], "bad_input")
        self.assertEqual(statuses[1:-1], ["decided", "rate_limited"] * (len(depth) // 2))
        # The cumulative counts agree too.
        last_c, last_p = cpp.decisions[stamps[-1]], py.decisions[stamps[-1]]
        self.assertEqual(
            dict(zip(last_c.count_names, last_c.count_values, strict=True)),
            dict(zip(last_p.count_names, last_p.count_values, strict=True)),
        )


if __name__ == "__main__":
    rospy.init_node("infer_node_parity_check")
    rostest.rosrun("quad_il", "infer_node_parity_check", InferNodeParity)
