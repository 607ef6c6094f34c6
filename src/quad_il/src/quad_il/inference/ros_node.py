"""The Python policy node (rospy): the same interface, preprocessing, output and safety layer as the C++
quad_policy/policy_node (docs/inference.md). nodes/policy_node.py runs `main()`.

Per depth frame: pair it with the newest odometry not newer than the frame, decide (PolicyDecider), publish
the trajectory to fly on planner/bspline and send it to the tracker action tracker/track_bspline (a refused
plan sends the stopping trajectory, or switches the tracker to hover), publish policy/decision, wait until
the tracker has taken the trajectory (bounded by ~tracker_accept_timeout_s, so in lockstep it takes effect
at the same step in every run), then acknowledge the frame. Goals are answered on policy/status."""

from __future__ import annotations

import collections
import math
import sys
import threading
import time
from dataclasses import dataclass

import actionlib
import numpy as np
import rospy
import tf2_ros
import torch
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import String

from quad_il.inference.config import PolicyConfigError, PolicyNodeConfig, load_policy_config
from quad_il.inference.decider import DecisionInputs, PolicyDecider
from quad_il.inference.geometry import pose_matrix
from quad_il.inference.input_checks import depth_layout_problem, depth_size_problem, state_problem
from quad_il.inference.messages import bspline_message
from quad_il.inference.meta import PolicyFormatError
from quad_il.inference.policy import LoadedPolicy, configure_threads
from quad_il.inference.safety import CameraModel
from quad_msgs.msg import (
    Bspline,
    EpisodeStatus,
    FrameAck,
    PolicyDecision,
    TrackBsplineAction,
    TrackBsplineGoal,
)
from quad_msgs.srv import SwitchTracker


@dataclass(frozen=True)
class OdomSample:
    stamp_s: float
    p: np.ndarray
    v: np.ndarray
    q: np.ndarray  # x, y, z, w


def depth_from_image(msg: Image) -> tuple[np.ndarray | None, str]:
    """32FC1 little-endian image -> ((H, W) float32 view, ""); any other layout: (None, the reason)."""
    problem = depth_layout_problem(
        msg.encoding, bool(msg.is_bigendian), msg.width, msg.height, msg.step, len(msg.data)
    )
    if problem:
        return None, problem
    flat = np.frombuffer(msg.data, dtype="<f4", count=(msg.step // 4) * msg.height)
    return flat.reshape(msg.height, msg.step // 4)[:, : msg.width], ""


class PolicyNode:
    def __init__(
        self,
        cfg: PolicyNodeConfig,
        tracker_accept_timeout_s: float = 1.0,
        odom_period_s: float = 0.005,
        odom_wait_s: float = 0.2,
    ) -> None:
        """tracker_accept_timeout_s: longest wait for the tracker to take a trajectory before the frame is
        acknowledged; odom_period_s: the simulator's odometry period (a frame waits for its period's, at
        most odom_wait_s of wall time)."""
        self.cfg = cfg
        self.tracker_accept_timeout_s = tracker_accept_timeout_s
        self.odom_period_s = odom_period_s
        if not (math.isfinite(odom_wait_s) and odom_wait_s > 0.0):
            raise PolicyConfigError(f"~odom_wait_s must be a finite number > 0, got {odom_wait_s}")
        self.odom_wait_s = odom_wait_s
        configure_threads(cfg.num_threads)
        policy = LoadedPolicy(cfg.policy_file)
        self.decider = PolicyDecider(policy, cfg.safety, cfg.refusal, cfg.recovery, cfg.keeping)
        m = policy.meta
        entry = "forward_net" if policy.has_forward_net else "forward_prepared"
        rospy.loginfo(
            f"policy_node (py): {cfg.policy_file} (input {m.input_width}x{m.input_height}, state "
            f"{m.state_frame}, output {m.output_frame} {m.representation}, K = {m.num_ctrl_pts} over "
            f"{m.horizon_s:.2f} s, network entry {entry}), {cfg.num_threads} thread(s), refusal action "
            f"{cfg.refusal.action}, recovery goal turns {list(cfg.recovery.goal_yaw_offsets_deg)} deg, "
            f"steering clearance {cfg.recovery.steer_clearance_m:g} m, "
            f"final approach {cfg.recovery.final_approach_m:g} m"
        )
        try:
            self._warm_up(policy)
        except RuntimeError as e:
            # A file whose methods exist but do not take a policy's inputs (issue 30): name the file.
            raise PolicyFormatError(
                f"{cfg.policy_file}: the policy's forward pass fails on a test input: {e}"
            ) from None
        self.lock = threading.Lock()
        self.odom_cv = threading.Condition(self.lock)  # an odometry message arrived
        self.odom: collections.deque[OdomSample] = collections.deque(maxlen=400)
        self.goal: np.ndarray | None = None
        self.camera_info: CameraInfo | None = None
        self.episode_id: int | None = None
        self.last_decision_stamp: rospy.Time | None = None
        self.hovering = False
        self.reset_decider = False  # a new episode began: reset the decider before its next decision
        self.T_body_camera: np.ndarray | None = None
        self.counts: dict[str, int] = {}
        self.traj_id = 0
        self.action_lock = threading.Lock()
        self.handles: collections.deque[actionlib.ClientGoalHandle] = collections.deque(maxlen=64)
        self.tracker_rejections = 0
        self.last_rejection = ""
        self.action_cv = threading.Condition(self.action_lock)
        # This frame's trajectory until the tracker answers it (depth thread only).
        self.sent: actionlib.ClientGoalHandle | None = None
        self.sent_traj_id = 0
        self.tracker_accept_timeouts = 0

        self.tf_buffer = tf2_ros.Buffer()
        self.tf_listener = tf2_ros.TransformListener(self.tf_buffer)
        # 100 like the decisions: a recorder that falls behind (3 s at 30 Hz) still gets every trajectory.
        self.bspline_pub = rospy.Publisher("planner/bspline", Bspline, queue_size=100)
        self.proposal_pub = rospy.Publisher("policy/proposal", Bspline, queue_size=100)
        self.decision_pub = rospy.Publisher("policy/decision", PolicyDecision, queue_size=100)
        self.ack_pub = rospy.Publisher("sim/frame_ack", FrameAck, queue_size=100)
        self.status_pub = rospy.Publisher("policy/status", String, queue_size=10, latch=True)
        self.switch = rospy.ServiceProxy("tracker/switch", SwitchTracker)
        self.client = (
            actionlib.ActionClient("tracker/track_bspline", TrackBsplineAction)
            if cfg.send_to_tracker
            else None
        )
        rospy.Subscriber("odom", Odometry, self._on_odom, queue_size=50, tcp_nodelay=True)
        rospy.Subscriber("planner/goal", PoseStamped, self._on_goal, queue_size=10, tcp_nodelay=True)
        rospy.Subscriber(
            "camera/depth/camera_info", CameraInfo, self._on_info, queue_size=2, tcp_nodelay=True
        )
        rospy.Subscriber("sim/status", EpisodeStatus, self._on_status, queue_size=10, tcp_nodelay=True)
        # A lockstepped simulator starts sending frames once this node subscribes to them; an acknowledgement
        # sent before the simulator has connected to our FrameAck publisher is lost (a lockstep timeout). So
        # subscribe to frames only after that connection exists (up to 5 s: a simulator that is not
        # lockstepped may never connect).
        deadline = time.monotonic() + 5.0
        while self.ack_pub.get_num_connections() == 0 and time.monotonic() < deadline:
            if rospy.is_shutdown():
                return
            time.sleep(0.01)
        # rospy gives each subscription its own thread: frames are decided while odometry keeps arriving.
        rospy.Subscriber("camera/depth/image", Image, self._on_depth, queue_size=2, tcp_nodelay=True)

    def _warm_up(self, policy: LoadedPolicy) -> None:
        """The first forward passes of a TorchScript module are slower (profiling executor): run them now."""
        m = policy.meta
        x = torch.full((1, 1, m.input_height, m.input_width), 0.5)
        s = torch.zeros(1, 13)
        z3, q = torch.zeros(1, 3), torch.tensor([[0.0, 0.0, 0.0, 1.0]])
        for _ in range(3):
            policy.run(x, s, z3, z3, q, z3)

    # ---- inputs ----
    def _on_odom(self, msg: Odometry) -> None:
        p, q, v = msg.pose.pose.position, msg.pose.pose.orientation, msg.twist.twist.linear
        o = OdomSample(
            msg.header.stamp.to_sec(),
            np.array([p.x, p.y, p.z]),
            np.array([v.x, v.y, v.z]),  # twist in the world frame (docs/CONVENTIONS.md)
            np.array([q.x, q.y, q.z, q.w]),
        )
        with self.odom_cv:
            self.odom.append(o)
            self.odom_cv.notify_all()

    def _on_goal(self, msg: PoseStamped) -> None:
        g = np.array([msg.pose.position.x, msg.pose.position.y, msg.pose.position.z])
        if not np.all(np.isfinite(g)):
            rospy.logwarn("policy_node (py): goal with NaN/Inf ignored")
            self.status_pub.publish(String(data="goal rejected: not finite"))
            return
        with self.lock:
            self.goal = g
        rospy.loginfo(f"policy_node (py): goal ({g[0]:.2f}, {g[1]:.2f}, {g[2]:.2f})")
        # After the goal is stored: an episode runner in lockstep releases the frame once it reads this.
        self.status_pub.publish(String(data=f"goal accepted: ({g[0]:.2f}, {g[1]:.2f}, {g[2]:.2f})"))

    def _on_info(self, msg: CameraInfo) -> None:
        with self.lock:
            self.camera_info = msg

    def _on_status(self, msg: EpisodeStatus) -> None:
        with self.lock:
            if self.episode_id is not None and self.episode_id != msg.episode_id:
                # A new episode: the goal, the odometry and the plan state belong to the previous one.
                self.goal = None
                self.odom.clear()
                self.last_decision_stamp = None
                self.hovering = False
                self.reset_decider = True
                rospy.loginfo(f"policy_node (py): episode {msg.episode_id} started: waiting for its goal")
            self.episode_id = msg.episode_id

    # ---- one frame ----
    def _count(self, name: str) -> None:
        self.counts[name] = self.counts.get(name, 0) + 1

    def _on_depth(self, msg: Image) -> None:
        out = PolicyDecision()
        out.header = msg.header
        out.node = "py"
        out.frame_seq = msg.header.seq
        out.action = "none"
        try:
            self._handle(msg, out)
        except Exception as e:  # noqa: BLE001 - a node must not die on one frame; the reason is published
            rospy.logerr_throttle(5.0, f"policy_node (py): frame failed: {e}")
            self._skip("bad_input", str(e), out)
        out.count_names = list(self.counts)
        out.count_values = list(self.counts.values())
        with self.action_lock:
            out.tracker_rejections = self.tracker_rejections
            out.last_tracker_rejection = self.last_rejection
        self.decision_pub.publish(out)
        self._wait_tracker_accept()
        # Lockstep: acknowledge after deciding (and sending), whatever the outcome.
        self.ack_pub.publish(
            FrameAck(consumer=self.cfg.lockstep_consumer, frame_seq=msg.header.seq, stamp=msg.header.stamp)
        )

    def _skip(self, status: str, reason: str, out: PolicyDecision) -> None:
        out.status = status
        out.reason = reason
        self._count(status)

    def _refuse(self, reason: str, out: PolicyDecision) -> None:
        rospy.logwarn_throttle(2.0, f"policy_node (py): frame refused: {reason}")
        self._skip("bad_input", reason, out)

    def _handle(self, msg: Image, out: PolicyDecision) -> None:
        stamp = msg.header.stamp.to_sec()
        depth, layout = depth_from_image(msg)
        if depth is None:
            return self._refuse(layout, out)
        with self.odom_cv:
            # The frame's own odometry (its control period's, published before the frame) travels on another
            # topic: wait for it (at most odom_wait_s of wall time), so that which odometry a decision starts
            # from does not depend on message timing. Without it, the newest older one is used.
            self.odom_cv.wait_for(
                lambda: bool(self.odom) and self.odom[-1].stamp_s > stamp - self.odom_period_s + 1e-6,
                self.odom_wait_s,
            )
            goal = self.goal
            odom = next((o for o in reversed(self.odom) if o.stamp_s <= stamp + 1e-9), None)
            info = self.camera_info
            last_decision = self.last_decision_stamp
            reset_decider, self.reset_decider = self.reset_decider, False
        if reset_decider:
            self.decider.reset()  # a new episode: no stops in a row, no remembered depth frames
        if goal is None:
            return self._skip("no_goal", "no goal for this episode yet", out)
        if odom is None:
            return self._skip("no_odometry", "no odometry at or before the frame", out)
        if info is None:
            return self._skip("no_camera_info", "no camera info yet", out)
        # Bad input is refused before anything is computed from it: no trajectory is sent for this frame, so
        # the tracker flies on along the plan it has (or holds) (docs/CONVENTIONS.md, fault table).
        size = depth_size_problem(msg.width, msg.height, int(info.width), int(info.height))
        if size:
            return self._refuse(size, out)
        state = state_problem(odom.p, odom.v, odom.q, odom.stamp_s)
        if state:
            return self._refuse(state, out)
        if stamp - odom.stamp_s > self.cfg.max_odom_age_s:
            return self._skip("stale_odometry", f"latest odometry is {stamp - odom.stamp_s:.6f} s old", out)
        if float(np.linalg.norm(odom.p - goal)) < self.cfg.goal_tolerance_m:
            return self._skip("goal_reached", "within goal_tolerance_m of the goal", out)
        # In integer nanoseconds (as the C++ node, llround), so both nodes decide on exactly the same frames.
        if (
            self.cfg.replan_rate_hz > 0.0
            and last_decision is not None
            and (msg.header.stamp - last_decision).to_nsec() < math.floor(1e9 / self.cfg.replan_rate_hz + 0.5)
        ):
            return self._skip("rate_limited", "replan_rate_hz", out)
        if self.T_body_camera is None:
            # No waiting: a lockstepped simulator holds ROS time during this frame (the next frame retries).
            try:
                t = self.tf_buffer.lookup_transform("base_link", msg.header.frame_id, rospy.Time(0)).transform
            except (
                tf2_ros.LookupException,
                tf2_ros.ConnectivityException,
                tf2_ros.ExtrapolationException,
            ) as e:
                rospy.logwarn_throttle(
                    5.0, f"policy_node (py): no transform base_link -> {msg.header.frame_id}: {e}"
                )
                return self._skip("no_camera_pose", str(e), out)
            self.T_body_camera = pose_matrix(
                [t.translation.x, t.translation.y, t.translation.z],
                [t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w],
            )
        camera = CameraModel(
            int(info.width),
            int(info.height),
            float(info.K[0]),
            float(info.K[4]),
            float(info.K[2]),
            float(info.K[5]),
            pose_matrix(odom.p, odom.q) @ self.T_body_camera,
        )
        try:
            d = self.decider.decide(DecisionInputs(stamp, depth, camera, odom.p, odom.v, odom.q, goal))
        except ValueError as e:
            rospy.logwarn_throttle(5.0, f"policy_node (py): no decision: {e}")
            return self._skip("bad_input", str(e), out)
        with self.lock:
            self.last_decision_stamp = msg.header.stamp
            hovering = self.hovering
        t0 = time.perf_counter()
        send = d.to_send()
        bspline = None
        if send is not None:
            self.traj_id += 1
            bspline = bspline_message(send, self.traj_id, msg.header.stamp)
        out.message_ms = d.timings.decode_ms + 1e3 * (time.perf_counter() - t0)
        out.status = "decided"
        out.verdict = d.safety.verdict.label
        out.accepted = d.accepted
        out.reason = d.safety.reason
        out.preprocess_ms = d.timings.preprocess_ms
        out.forward_ms = d.timings.forward_ms
        out.decision_ms = out.preprocess_ms + out.forward_ms + out.message_ms
        out.safety_ms = d.timings.safety_ms
        self._count(out.verdict)
        self.proposal_pub.publish(
            bspline_message(d.proposed, self.traj_id if d.accepted else 0, msg.header.stamp)
        )
        if not d.accepted:
            rospy.logwarn_throttle(2.0, f"policy_node (py): plan refused: {d.safety.reason}")
        if d.recovery is not None:
            self._count("steered" if d.steered else "recovered")
            out.reason += d.recovery_text(self.decider.policy.meta.hypotheses)
        if d.final is not None:
            self._count("final_approach")
            out.reason += "; final approach: straight to the goal (not the network's plan)"
        if d.kept is not None:
            self._count("committed" if d.committed else "kept")
            out.reason += (
                f"; {'committed to' if d.committed else 'kept'} the plan sent "
                f"{stamp - d.kept.start_time_s:.2f} s before (its rest is clear)"
            )
        if d.turn_rate_radps != 0.0:
            self._count("turning")
            out.reason += (
                f"; turning in place at {math.degrees(d.turn_rate_radps):.0f} deg/s, "
                f"backing off {d.turn_backoff_m:.2f} m"
            )
        if bspline is not None:
            if d.final is not None:
                out.action = "final_approach"
            elif d.recovery is not None:
                out.action = "steer" if d.steered else "recovery"
            else:
                out.action = "policy" if d.accepted else ("turn" if d.turn_rate_radps != 0.0 else "stop")
            out.traj_id = bspline.traj_id
            self.bspline_pub.publish(bspline)
            self._send_to_tracker(bspline)
            self._set_hovering(False)
        elif d.kept is not None:
            out.action = "keep"  # the tracker flies on along the plan sent before
        else:
            out.action = "hover"
            if not hovering:
                self._set_hovering(self._switch_to_hover())

    # ---- tracker ----
    def _send_to_tracker(self, bspline: Bspline) -> None:
        if self.client is None:
            return
        # Not wait_for_server: it waits in ROS time, which a lockstepped simulator holds during this frame. As
        # the C++ node: an unconfirmed connection is counted as an event and the goal sent anyway.
        if self.client.pub_goal.get_num_connections() == 0:
            rospy.logwarn_throttle(
                5.0, "policy_node (py): tracker action tracker/track_bspline not connected"
            )
            self._count("tracker_not_connected")
        gh = self.client.send_goal(TrackBsplineGoal(bspline=bspline), transition_cb=self._on_transition)
        with self.action_lock:
            self.handles.append(gh)  # keeps the goal tracked until its result arrives
        # Not connected: no answer is coming (the goal may still arrive; it is counted above).
        if self.client.pub_goal.get_num_connections() > 0:
            self.sent, self.sent_traj_id = gh, bspline.traj_id

    def _wait_tracker_accept(self) -> None:
        """Wait (wall time, at most tracker_accept_timeout_s) until the tracker has answered this frame's
        trajectory. In lockstep the simulator steps on once the frame is acknowledged; the tracker applies a
        trajectory from the first odometry after it took it, so without this wait the step it starts at would
        depend on message timing."""
        gh, self.sent = self.sent, None
        if gh is None:
            return
        deadline = time.monotonic() + self.tracker_accept_timeout_s
        while gh.get_comm_state() == actionlib.CommState.WAITING_FOR_GOAL_ACK:
            if rospy.is_shutdown():
                return
            left = deadline - time.monotonic()
            if left <= 0:
                self.tracker_accept_timeouts += 1
                self._count("tracker_accept_timeout")
                rospy.logwarn(
                    f"policy_node (py): the tracker did not take trajectory {self.sent_traj_id} within "
                    f"{self.tracker_accept_timeout_s:g} s ({self.tracker_accept_timeouts} times so far)"
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
            with self.action_lock:
                self.tracker_rejections += 1
                self.last_rejection = result.reason if result is not None else gh.get_goal_status_text()
            rospy.logwarn_throttle(
                2.0, f"policy_node (py): tracker rejected a trajectory: {self.last_rejection}"
            )

    def _set_hovering(self, hovering: bool) -> None:
        with self.lock:
            self.hovering = hovering

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
        cfg = load_policy_config(rospy.get_param("~config"))
        overrides = {}
        policy_file = rospy.get_param("~policy_file", "")
        if policy_file:
            overrides["policy_file"] = policy_file
        threads = int(rospy.get_param("~num_threads", 0))
        if threads > 0:
            overrides["num_threads"] = threads
        if rospy.has_param("~send_to_tracker"):
            overrides["send_to_tracker"] = bool(rospy.get_param("~send_to_tracker"))
        cfg = cfg.model_copy(update=overrides)
        if not cfg.policy_file:
            raise PolicyConfigError("no policy file: set policy_file in the config or ~policy_file")
        PolicyNode(
            cfg,
            float(rospy.get_param("~tracker_accept_timeout_s", 1.0)),
            float(rospy.get_param("~odom_period_s", 0.005)),
            float(rospy.get_param("~odom_wait_s", 0.2)),
        )
    except (KeyError, PolicyConfigError, PolicyFormatError, FileNotFoundError, RuntimeError) as e:
        rospy.logfatal(f"policy_node (py): {e}")
        rospy.signal_shutdown(f"policy_node (py): {e}")
        return 1
    rospy.spin()
    return 0


if __name__ == "__main__":
    sys.exit(main())
