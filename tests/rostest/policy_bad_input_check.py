#!/usr/bin/env python3
"""rostest node of policy_bad_input.test (issue 30, fault table: NaN or inf in odometry, a depth image of the
wrong encoding or size). The C++ node (quad_policy/policy_node, namespace /cpp) and the Python node (quad_il
policy_node.py, namespace /py) fly the default node config (config/policy_keep.yaml) with the goal-line test
policy; this node plays the simulator (odometry, camera info, depth frames, the camera's static transform) and
the tracker (a TrackBspline action server and the tracker/switch service that record what they get).

Between two good frames, each of which must send a trajectory to the tracker, come frames with NaN position,
inf velocity / NaN orientation odometry, 16UC1 and rgb8 encodings, a size that is not camera_info's, and data
one row short and one row long of step * height. Each bad frame must be refused by both nodes with status
bad_input and the reason naming the fault (the same text in both), acknowledged, with nothing sent: no
trajectory to the tracker, no B-spline, no switch to hover (the tracker flies on along the plan it has). Both
nodes must be alive at the end and decide the last good frame as usual."""

from __future__ import annotations

import math
import shutil
import tempfile
import threading
import time
import unittest
from pathlib import Path

import actionlib
import numpy as np
import rospy
import rostest
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from policy_nodes_common import NAMESPACES, broadcast_camera_mount, policy_nodes
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import String

from quad_il.inference.random_policy import export_goal_line_policy
from quad_msgs.msg import Bspline, FrameAck, PolicyDecision, TrackBsplineAction
from quad_msgs.srv import SwitchTracker, SwitchTrackerResponse

H, W = 60, 80
K = [387.2 * W / 640, 0, (W - 1) / 2, 0, 387.2 * H / 480, (H - 1) / 2, 0, 0, 1]
GUARD_S = 60.0  # wall-time failure guard of every wait (each wait ends on its condition)
P0 = (0.0, 0.0, 1.5)
GOAL = (10.0, 0.0, 1.5)


def exact_time(t: float) -> rospy.Time:
    secs = math.floor(t)
    nsecs = round((t - secs) * 1e9)
    return rospy.Time(secs + nsecs // 1_000_000_000, nsecs % 1_000_000_000)


def key(stamp: rospy.Time) -> float:
    return round(stamp.to_sec(), 6)


def odometry(stamp: float, p=P0, v=(0.0, 0.0, 0.0), q=(0.0, 0.0, 0.0, 1.0)) -> Odometry:
    m = Odometry()
    m.header.stamp = exact_time(stamp)
    m.header.frame_id, m.child_frame_id = "world", "base_link"
    m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.position.z = p
    o = m.pose.pose.orientation
    o.x, o.y, o.z, o.w = q
    m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z = v
    return m


def image(stamp: float, encoding: str, width: int, height: int, step: int, data: bytes) -> Image:
    m = Image()
    m.header.stamp = exact_time(stamp)
    m.header.frame_id = "camera"
    m.encoding, m.is_bigendian = encoding, 0
    m.width, m.height, m.step = width, height, step
    m.data = data
    return m


def free_depth(stamp: float, width: int = W, height: int = H, extra_rows: int = 0) -> Image:
    """Nothing in view (+inf, REP 118); extra_rows < 0 / > 0: data rows missing / added."""
    rows = np.full((height + extra_rows, width), np.inf, dtype="<f4")
    return image(stamp, "32FC1", width, height, 4 * width, rows.tobytes())


class FakeTracker:
    """One namespace's tracker: accepts every TrackBspline goal and every switch, recording both."""

    def __init__(self, ns: str) -> None:
        self.lock = threading.Lock()
        self.goal_starts: list[float] = []
        self.switches: list[str] = []
        self.server = actionlib.ActionServer(
            f"/{ns}/tracker/track_bspline", TrackBsplineAction, self._on_goal, auto_start=False
        )
        self.server.start()
        self.switch = rospy.Service(f"/{ns}/tracker/switch", SwitchTracker, self._on_switch)

    def _on_goal(self, gh) -> None:
        with self.lock:
            self.goal_starts.append(key(gh.get_goal().bspline.start_time))
        gh.set_accepted()

    def _on_switch(self, req) -> SwitchTrackerResponse:
        with self.lock:
            self.switches.append(req.tracker)
        return SwitchTrackerResponse(success=True, message="")

    def connected(self) -> bool:
        return (
            self.server.goal_sub.get_num_connections() > 0
            and self.server.status_pub.get_num_connections() > 0
        )


class NodeIO:
    """One namespace's publishers and everything its node publishes."""

    def __init__(self, ns: str) -> None:
        self.lock = threading.Lock()
        self.cv = threading.Condition(self.lock)
        self.decisions: dict[float, PolicyDecision] = {}
        self.acks: set[float] = set()
        self.bsplines: dict[int, float] = {}  # traj_id -> start time
        self.status: list[str] = []
        self.tracker = FakeTracker(ns)
        self.odom = rospy.Publisher(f"/{ns}/odom", Odometry, queue_size=100, tcp_nodelay=True)
        self.depth = rospy.Publisher(f"/{ns}/camera/depth/image", Image, queue_size=100, tcp_nodelay=True)
        self.info = rospy.Publisher(f"/{ns}/camera/depth/camera_info", CameraInfo, queue_size=1, latch=True)
        self.goal = rospy.Publisher(f"/{ns}/planner/goal", PoseStamped, queue_size=1, latch=True)
        rospy.Subscriber(f"/{ns}/policy/decision", PolicyDecision, self._on_decision, queue_size=100)
        rospy.Subscriber(f"/{ns}/sim/frame_ack", FrameAck, self._on_ack, queue_size=100)
        rospy.Subscriber(f"/{ns}/planner/bspline", Bspline, self._on_bspline, queue_size=100)
        rospy.Subscriber(f"/{ns}/policy/status", String, self._on_status, queue_size=10)

    def _on_decision(self, m: PolicyDecision) -> None:
        with self.cv:
            self.decisions[key(m.header.stamp)] = m
            self.cv.notify_all()

    def _on_ack(self, m: FrameAck) -> None:
        with self.cv:
            self.acks.add(key(m.stamp))
            self.cv.notify_all()

    def _on_bspline(self, m: Bspline) -> None:
        with self.cv:
            self.bsplines[m.traj_id] = key(m.start_time)
            self.cv.notify_all()

    def _on_status(self, m: String) -> None:
        with self.cv:
            self.status.append(m.data)
            self.cv.notify_all()

    def wait(self, predicate, what: str) -> None:
        """Until predicate() holds: woken by this namespace's messages, and every 20 ms for conditions
        that arrive otherwise (connections)."""
        deadline = time.monotonic() + GUARD_S
        with self.cv:
            while not predicate():
                if time.monotonic() > deadline:
                    raise AssertionError(f"no {what} within {GUARD_S:g} s")
                self.cv.wait(0.02)


class PolicyBadInput(unittest.TestCase):
    def test_bad_odometry_and_depth_are_refused_with_a_reason_and_nothing_sent(self) -> None:
        work = Path(tempfile.mkdtemp(prefix="policy_bad_input_"))
        self.addCleanup(shutil.rmtree, work, True)
        policy = export_goal_line_policy(work / "policy.ts")
        io = {ns: NodeIO(ns) for ns in NAMESPACES}
        tf = broadcast_camera_mount()
        # Wait on conditions: a frame waits for its odometry, the tracker's answer comes (guards only). An
        # overlay of the node config (both loaders merge it).
        config = work / "policy.yaml"
        config.write_text(
            f"overlay_of: {rospy.get_param('~policy_config')}\n"
            f"odom_wait_s: {GUARD_S}\ntracker_accept_timeout_s: {GUARD_S}\n"
        )
        params = {"config": str(config), "policy_file": str(policy)}
        with policy_nodes(params) as procs:
            self._run(io, tf)
            for p in procs:
                self.assertTrue(p.is_alive(), f"{p.name} died")

    def _send(self, io, stamp: float, depth: Image, odom: Odometry | None) -> dict[str, PolicyDecision]:
        """One frame to both nodes; their decisions once both acknowledged it."""
        k = round(stamp, 6)
        for n in io.values():
            if odom is not None:
                n.odom.publish(odom)
            n.depth.publish(depth)
        for ns, n in io.items():
            n.wait(lambda n=n: k in n.acks and k in n.decisions, f"{ns} decision and ack of frame {stamp}")
        return {ns: n.decisions[k] for ns, n in io.items()}

    def _run(self, io, tf) -> None:
        # Every connection up: frames and odometry reach both nodes, the acknowledgements, decisions and
        # B-splines reach us, the nodes hear the fake tracker and the camera's transform.
        deadline = time.monotonic() + GUARD_S
        while not (
            all(
                n.depth.get_num_connections() > 0
                and n.odom.get_num_connections() > 0
                and n.info.get_num_connections() > 0
                and n.goal.get_num_connections() > 0
                for n in io.values()
            )
            and tf.pub_tf.get_num_connections() >= len(io)
        ):
            self.assertLess(time.monotonic(), deadline, "the policy nodes did not subscribe")
            time.sleep(0.05)
        info = CameraInfo()
        info.header.frame_id = "camera"
        info.height, info.width = H, W
        info.K = K
        for n in io.values():
            n.info.publish(info)
        # A frame before the goal (the C++ node builds its action client at its first frame).
        for ns, d in self._send(io, 1.0, free_depth(1.0), odometry(0.998)).items():
            self.assertEqual(d.status, "no_goal", f"{ns}: {d.reason}")
        for ns, n in io.items():
            n.wait(n.tracker.connected, f"{ns} connection to the tracker action")
        goal = PoseStamped()
        goal.header.frame_id = "world"
        goal.pose.position.x, goal.pose.position.y, goal.pose.position.z = GOAL
        goal.pose.orientation.w = 1.0
        for ns, n in io.items():
            n.goal.publish(goal)
            n.wait(lambda n=n: any(s.startswith("goal accepted") for s in n.status), f"{ns} goal answer")

        # A good frame: a trajectory goes to the tracker. (The camera's transform may still be on its way:
        # then the next frame, 0.1 s later, retries.)
        stamp = 2.0
        while True:
            decisions = self._send(io, stamp, free_depth(stamp), odometry(stamp - 0.002))
            if all(d.status == "decided" for d in decisions.values()):
                break
            self.assertTrue(all(d.status == "no_camera_pose" for d in decisions.values()), decisions)
            stamp = round(stamp + 0.1, 6)
            self.assertLess(stamp, 2.95, "the nodes never got the camera's transform")
        good = [stamp]

        nan, inf = float("nan"), float("inf")
        bad = [
            (
                3.0,
                free_depth(3.0),
                odometry(2.998, p=(nan, 0.0, 1.5)),
                "odometry at 2.998000 s is not finite (position)",
            ),
            (
                4.0,
                free_depth(4.0),
                odometry(3.998, v=(inf, 0.0, 0.0), q=(0.0, 0.0, nan, 1.0)),
                "odometry at 3.998000 s is not finite (velocity, orientation)",
            ),
            (
                5.0,
                image(5.0, "16UC1", W, H, 2 * W, bytes(2 * W * H)),
                odometry(4.998),
                "depth frame encoding is '16UC1', not 32FC1",
            ),
            (
                6.0,
                image(6.0, "rgb8", W, H, 3 * W, bytes(3 * W * H)),
                odometry(5.998),
                "depth frame encoding is 'rgb8', not 32FC1",
            ),
            (
                7.0,
                free_depth(7.0, W // 2, H // 2),
                odometry(6.998),
                f"depth frame is {W // 2}x{H // 2}, camera_info is {W}x{H}",
            ),
            (
                8.0,
                free_depth(8.0, extra_rows=-1),
                odometry(7.998),
                f"depth frame has {4 * W * (H - 1)} data bytes, step * height = {4 * W * H}",
            ),
            (
                8.5,
                free_depth(8.5, extra_rows=1),
                odometry(8.498),
                f"depth frame has {4 * W * (H + 1)} data bytes, step * height = {4 * W * H}",
            ),
        ]
        for stamp, depth, odom, reason in bad:
            for ns, d in self._send(io, stamp, depth, odom).items():
                what = f"{ns}, frame {stamp}"
                self.assertEqual((d.status, d.reason), ("bad_input", reason), what)
                self.assertEqual((d.action, d.traj_id, d.accepted), ("none", 0, False), what)
            # Nothing reached the tracker: a goal sent for this frame would have been answered (and so
            # recorded) before the frame was acknowledged.
            for ns, n in io.items():
                with n.lock:
                    self.assertEqual(n.tracker.goal_starts, good, f"{ns}: a trajectory sent at frame {stamp}")

        # The nodes decide the next good frame as usual.
        decisions = self._send(io, 9.0, free_depth(9.0), odometry(8.998))
        good.append(9.0)
        for ns, d in decisions.items():
            self.assertEqual(d.status, "decided", f"{ns}: {d.reason}")
            self.assertGreater(d.traj_id, 0, f"{ns}: {d.action} {d.reason}")
        for ns, n in io.items():
            # B-splines travel on their own topic (in order): once the last one is in, all are.
            last = decisions[ns].traj_id
            n.wait(lambda n=n, last=last: last in n.bsplines, f"{ns} B-spline {last}")
            with n.lock:
                self.assertEqual(n.tracker.goal_starts, good, ns)
                self.assertEqual(sorted(n.bsplines.values()), good, ns)
                self.assertEqual(n.tracker.switches, [], f"{ns} switched the tracker")
            counts = dict(zip(decisions[ns].count_names, decisions[ns].count_values, strict=True))
            self.assertEqual(counts.get("bad_input"), len(bad), f"{ns}: {counts}")


if __name__ == "__main__":
    rospy.init_node("policy_bad_input_check")
    rostest.rosrun("quad_il", "policy_bad_input_check", PolicyBadInput)
