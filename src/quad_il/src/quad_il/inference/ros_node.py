"""The Python policy node (rospy): the C++ node's interface and decisions, with the network's preprocessing
and forward pass in torch and everything after it (decoding, safety layer, recovery, final approach, keeping,
the stopping trajectory) in the bound C++ decider (docs/inference.md). nodes/policy_node.py runs `main()`.

Per depth frame: pair it with the newest odometry not newer than the frame (quad_il.frame_pairing), decide,
publish the trajectory to fly on planner/bspline (and as a marker on policy/plan_marker), send it to the
tracker action tracker/track_bspline (a refusal sends the stopping trajectory, or switches the tracker to
hover), publish policy/decision, wait (at most tracker_accept_timeout_s) until the tracker has taken it, so in
lockstep it takes effect at the same step in every run, then acknowledge the frame. Goals are answered on
policy/status. Every parameter comes from the policy config (~config); ~policy_file, ~num_threads (> 0) and
~send_to_tracker override its keys when set."""

from __future__ import annotations

import collections
import math
import sys
import threading
import time

import actionlib
import numpy as np
import rospy
import tf2_ros
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import String
from visualization_msgs.msg import Marker

from quad_il.frame_pairing import newest_at_or_before, period_arrived
from quad_il.inference.config import PolicyConfigError, PolicyNodeConfig, load_policy_config
from quad_il.inference.core import (
    CameraModel,
    PolicyDecider,
    depth_size_problem,
    state_problem,
)
from quad_il.inference.messages import bspline_message, depth_from_image, plan_marker, pose
from quad_il.inference.policy import LoadedPolicy, configure_threads
from quad_il.ros_params import MissingParameterError, require_param
from quad_msgs.msg import (
    Bspline,
    EpisodeStatus,
    FrameAck,
    PolicyDecision,
    TrackBsplineAction,
    TrackBsplineGoal,
)
from quad_msgs.srv import SwitchTracker


class PolicyNode:
    def __init__(self, cfg: PolicyNodeConfig) -> None:
        self.cfg = cfg
        configure_threads(cfg.num_threads)
        self.policy = LoadedPolicy(cfg.policy_file)
        self.decider = PolicyDecider(self.policy.meta, cfg.safety, cfg.refusal, cfg.recovery, cfg.keeping)
        m = self.policy.meta
        rospy.loginfo(f"policy_node (py): {cfg.policy_file}, output {m.output_frame} {m.representation}")
        self.policy.warm_up()
        self.lock = threading.Lock()
        self.odom_cv = threading.Condition(self.lock)  # an odometry message arrived
        self.odom: collections.deque = collections.deque(maxlen=400)  # (stamp_s, p, v, q xyzw), oldest first
        self.goal: np.ndarray | None = None
        self.camera_info: CameraInfo | None = None
        self.episode_id: int | None = None
        self.last_decision_stamp: rospy.Time | None = None
        self.hovering = False
        self.reset_decider = False  # a new episode began: reset the decider before its next decision
        self.T_body_camera: np.ndarray | None = None
        self.counts: dict[str, int] = {}
        self.traj_id = 0
        self.action_cv = threading.Condition()
        self.handles: collections.deque = collections.deque(maxlen=64)  # goals tracked until their results
        self.tracker_rejections = 0
        self.last_rejection = ""
        self.sent, self.sent_traj_id = (
            None,
            0,
        )  # this frame's trajectory (goal handle) until the tracker answers
        self.tf_buffer = tf2_ros.Buffer()
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        # 100 like the decisions: a recorder that falls behind (3 s at 30 Hz) still gets every trajectory.
        self.bspline_pub = rospy.Publisher("planner/bspline", Bspline, queue_size=100)
        self.proposal_pub = rospy.Publisher("policy/proposal", Bspline, queue_size=100)
        self.marker_pub = rospy.Publisher("policy/plan_marker", Marker, queue_size=10)
        self.decision_pub = rospy.Publisher("policy/decision", PolicyDecision, queue_size=100)
        self.ack_pub = rospy.Publisher("sim/frame_ack", FrameAck, queue_size=100)
        self.status_pub = rospy.Publisher("policy/status", String, queue_size=10, latch=True)
        self.switch = rospy.ServiceProxy("tracker/switch", SwitchTracker)
        self.client = (
            actionlib.ActionClient("tracker/track_bspline", TrackBsplineAction)
            if cfg.send_to_tracker
            else None
        )
        for topic, msg_type, cb, size in [
            ("odom", Odometry, self._on_odom, 50),
            ("planner/goal", PoseStamped, self._on_goal, 10),
            ("camera/depth/camera_info", CameraInfo, self._on_info, 2),
            ("sim/status", EpisodeStatus, self._on_status, 10),
        ]:
            rospy.Subscriber(topic, msg_type, cb, queue_size=size, tcp_nodelay=True)
        # An acknowledgement sent before a lockstepped simulator has connected to our FrameAck publisher is
        # lost: subscribe to frames only once it has (up to 5 s: an unlockstepped one never does).
        deadline = time.monotonic() + 5.0
        while self.ack_pub.get_num_connections() == 0 and time.monotonic() < deadline:
            if rospy.is_shutdown():
                return
            time.sleep(0.01)
        # rospy gives each subscription its own thread: frames are decided while odometry keeps arriving.
        rospy.Subscriber("camera/depth/image", Image, self._on_depth, queue_size=2, tcp_nodelay=True)

    # ---- inputs ----
    def _on_odom(self, msg: Odometry) -> None:
        p, q, v = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
        sample = (msg.header.stamp.to_sec(), np.array([p.x, p.y, p.z]), np.array([v.x, v.y, v.z]))
        with self.odom_cv:
            self.odom.append((*sample, np.array([q.x, q.y, q.z, q.w])))  # twist in the world frame
            self.odom_cv.notify_all()

    def _on_goal(self, msg: PoseStamped) -> None:
        g = np.array([msg.pose.position.x, msg.pose.position.y, msg.pose.position.z])
        if not np.all(np.isfinite(g)):
            rospy.logwarn("policy_node (py): goal with NaN/Inf ignored")
            self.status_pub.publish(String(data="goal rejected: not finite"))
            return
        with self.lock:
            self.goal = g
        # After the goal is stored: an episode runner in lockstep releases the frame once it reads this.
        self.status_pub.publish(String(data=f"goal accepted: ({g[0]:.2f}, {g[1]:.2f}, {g[2]:.2f})"))

    def _on_info(self, msg: CameraInfo) -> None:
        with self.lock:
            self.camera_info = msg

    def _on_status(self, msg: EpisodeStatus) -> None:
        with self.lock:
            if self.episode_id is not None and self.episode_id != msg.episode_id:
                # A new episode: the goal, the odometry and the plan state belong to the previous one.
                self.goal, self.last_decision_stamp = None, None
                self.odom.clear()
                self.hovering, self.reset_decider = False, True
            self.episode_id = msg.episode_id

    # ---- one frame ----
    def _count(self, name: str) -> None:
        self.counts[name] = self.counts.get(name, 0) + 1

    def _on_depth(self, msg: Image) -> None:
        out = PolicyDecision(header=msg.header, node="py", frame_seq=msg.header.seq, action="none")
        try:
            self._handle(msg, out)
        except Exception as e:  # noqa: BLE001 - a node must not die on one frame; the reason is published
            rospy.logerr_throttle(5.0, f"policy_node (py): frame failed: {e}")
            self._skip("bad_input", str(e), out)
        out.count_names, out.count_values = list(self.counts), list(self.counts.values())
        with self.action_cv:
            out.tracker_rejections, out.last_tracker_rejection = self.tracker_rejections, self.last_rejection
        self.decision_pub.publish(out)
        self._wait_tracker_accept()
        # Lockstep: acknowledge after deciding (and sending), whatever the outcome.
        ack = FrameAck(consumer=self.cfg.lockstep_consumer, frame_seq=msg.header.seq, stamp=msg.header.stamp)
        self.ack_pub.publish(ack)

    def _skip(self, status: str, reason: str, out: PolicyDecision) -> None:
        out.status, out.reason = status, reason
        self._count(status)
        if status == "bad_input":
            rospy.logwarn_throttle(2.0, f"policy_node (py): frame refused: {reason}")

    def _handle(self, msg: Image, out: PolicyDecision) -> None:
        stamp = msg.header.stamp.to_sec()
        depth, layout = depth_from_image(msg)
        if depth is None:
            return self._skip("bad_input", layout, out)
        with self.odom_cv:
            # Wait (at most odom_wait_s, wall time) for the frame's own odometry, so which odometry a decision
            # starts from does not depend on message timing; without it, the newest older one is used.
            self.odom_cv.wait_for(
                lambda: bool(self.odom) and period_arrived(self.odom[-1][0], stamp, self.cfg.odom_period_s),
                self.cfg.odom_wait_s,
            )
            i = newest_at_or_before([o[0] for o in self.odom], stamp)
            odom = self.odom[i] if i >= 0 else None
            goal, info, last_decision = self.goal, self.camera_info, self.last_decision_stamp
            reset_decider, self.reset_decider = self.reset_decider, False
        if reset_decider:
            self.decider.reset()
        if goal is None:
            return self._skip("no_goal", "no goal for this episode yet", out)
        if odom is None:
            return self._skip("no_odometry", "no odometry at or before the frame", out)
        if info is None:
            return self._skip("no_camera_info", "no camera info yet", out)
        odom_stamp, p, v, q = odom
        # Bad input is refused before anything is computed from it: nothing is sent for this frame, so the
        # tracker flies on along the plan it has (docs/CONVENTIONS.md, fault table).
        problem = depth_size_problem(msg.width, msg.height, info.width, info.height)
        problem = problem or state_problem(p, v, q, odom_stamp)
        if problem:
            return self._skip("bad_input", problem, out)
        if stamp - odom_stamp > self.cfg.max_odom_age_s:
            return self._skip("stale_odometry", f"latest odometry is {stamp - odom_stamp:.6f} s old", out)
        if float(np.linalg.norm(p - goal)) < self.cfg.goal_tolerance_m:
            return self._skip("goal_reached", "within goal_tolerance_m of the goal", out)
        # In integer nanoseconds (as the C++ node, llround), so both nodes decide on exactly the same frames.
        period_ns = math.floor(1e9 / self.cfg.replan_rate_hz + 0.5) if self.cfg.replan_rate_hz > 0 else 0
        if last_decision is not None and (msg.header.stamp - last_decision).to_nsec() < period_ns:
            return self._skip("rate_limited", "replan_rate_hz", out)
        if self.T_body_camera is None:
            # No waiting: a lockstepped simulator holds ROS time during this frame (the next frame retries).
            try:
                t = self.tf_buffer.lookup_transform("base_link", msg.header.frame_id, rospy.Time(0)).transform
            except tf2_ros.TransformException as e:
                return self._skip("no_camera_pose", str(e), out)
            r = t.rotation
            self.T_body_camera = pose(np.array([t.translation.x, t.translation.y, t.translation.z]),
                                      np.array([r.x, r.y, r.z, r.w]))  # fmt: skip
        K = info.K
        camera = CameraModel(info.width, info.height, K[0], K[4], K[2], K[5], pose(p, q) @ self.T_body_camera)
        try:
            d, pre_ms, fwd_ms = self.policy.decide(self.decider, stamp, depth, camera, p, v, q, goal)
        except ValueError as e:
            return self._skip("bad_input", str(e), out)
        with self.lock:
            self.last_decision_stamp = msg.header.stamp
            hovering = self.hovering
        t0 = time.perf_counter()
        send = d.to_send
        if send is not None:
            self.traj_id += 1
            bspline = bspline_message(send, self.traj_id, msg.header.stamp)
        out.message_ms = d.timings.decode_ms + 1e3 * (time.perf_counter() - t0)
        summary = d.summary(self.policy.meta.hypotheses, stamp)
        out.status, out.verdict, out.action = "decided", d.verdict_label, summary.action
        out.accepted, out.reason = d.accepted, summary.reason
        out.preprocess_ms, out.forward_ms, out.safety_ms = pre_ms, fwd_ms, d.timings.safety_ms
        out.decision_ms = out.preprocess_ms + out.forward_ms + out.message_ms
        for name in [out.verdict, *summary.events]:
            self._count(name)
        self.proposal_pub.publish(
            bspline_message(d.proposed, self.traj_id if d.accepted else 0, msg.header.stamp)
        )
        if send is not None:
            out.traj_id = bspline.traj_id
            self.bspline_pub.publish(bspline)
            self.marker_pub.publish(plan_marker(send, msg.header, "policy_py"))
            self._send_to_tracker(bspline)
            with self.lock:
                self.hovering = False
        elif out.action == "hover" and not hovering:
            ok = self._switch_to_hover()
            with self.lock:
                self.hovering = ok

    # ---- tracker ----
    def _send_to_tracker(self, bspline: Bspline) -> None:
        if self.client is None:
            return
        # Not wait_for_server: it waits in ROS time, which a lockstepped simulator holds during this frame. As
        # the C++ node: an unconfirmed connection is counted as an event and the goal sent anyway.
        connected = self.client.pub_goal.get_num_connections() > 0
        if not connected:
            self._count("tracker_not_connected")
        gh = self.client.send_goal(TrackBsplineGoal(bspline=bspline), transition_cb=self._on_transition)
        with self.action_cv:
            self.handles.append(gh)
        if connected:  # else no answer is coming
            self.sent, self.sent_traj_id = gh, bspline.traj_id

    def _wait_tracker_accept(self) -> None:
        """Wait (wall time, at most tracker_accept_timeout_s) until the tracker has answered this frame's
        trajectory: the tracker applies it from the first odometry after it took it, so without this wait the
        lockstep step it starts at would depend on message timing."""
        gh, self.sent = self.sent, None
        if gh is None:
            return
        deadline = time.monotonic() + self.cfg.tracker_accept_timeout_s
        while gh.get_comm_state() == actionlib.CommState.WAITING_FOR_GOAL_ACK and not rospy.is_shutdown():
            left = deadline - time.monotonic()
            if left <= 0:
                self._count("tracker_accept_timeout")
                rospy.logwarn(
                    f"policy_node (py): the tracker did not take trajectory {self.sent_traj_id} in time"
                )
                return
            with self.action_cv:  # woken by any transition; the short timeout covers a wake-up missed
                self.action_cv.wait(min(left, 0.002))

    def _on_transition(self, gh: actionlib.ClientGoalHandle) -> None:
        with self.action_cv:
            self.action_cv.notify_all()
            if gh.get_comm_state() != actionlib.CommState.DONE:
                return
            if gh.get_terminal_state() == actionlib.GoalStatus.REJECTED:
                result = gh.get_result()
                self.tracker_rejections += 1
                self.last_rejection = result.reason if result is not None else gh.get_goal_status_text()

    def _switch_to_hover(self) -> bool:
        try:
            resp = self.switch(tracker="hover")
            if resp.success:
                return True
            reason = resp.message
        except rospy.ServiceException as e:
            reason = str(e)
        rospy.logwarn_throttle(5.0, f"policy_node (py): could not switch the tracker to hover: {reason}")
        self._count("hover_failed")
        return False


def main() -> int:
    rospy.init_node("policy_node")
    try:
        cfg = load_policy_config(
            require_param("~config", "the launch file (a policy config, config/policy.yaml)")
        )
        if rospy.has_param("~policy_file") and rospy.get_param("~policy_file"):
            cfg.policy_file = str(rospy.get_param("~policy_file"))
        if rospy.has_param("~num_threads") and int(rospy.get_param("~num_threads")) > 0:
            cfg.num_threads = int(rospy.get_param("~num_threads"))
        if rospy.has_param("~send_to_tracker"):
            cfg.send_to_tracker = bool(rospy.get_param("~send_to_tracker"))
        if not cfg.policy_file:
            raise PolicyConfigError("no policy file: set policy_file in the config or ~policy_file")
        PolicyNode(cfg)
    except (
        MissingParameterError,
        ValueError,
        FileNotFoundError,
        RuntimeError,
    ) as e:  # config and file errors
        rospy.logfatal(f"policy_node (py): {e}")
        rospy.signal_shutdown(f"policy_node (py): {e}")
        return 1
    rospy.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main())
