"""rospy adapter of the interactive collector (thin): `src/quad_il/nodes/imitation_collector.py`.

The logic it wraps is ROS-free: `collector_core` (pairing bookkeeping, episode state, odometry pairing, the
learner, the round's dataset; how frames are paired in lockstep is told there), `messages` (conversions),
`collector_config` (parameters). This module subscribes, converts, forwards the chosen plan to the tracker,
acknowledges frames and finalises the dataset and collector_manifest.json at shutdown. Tested with ROS by
tests/rostest/il_dagger_round.test and il_mega_round.test.

Topics (relative: they resolve in the node's namespace)
  in   odom, camera/depth/image (32FC1), camera/depth/camera_info (the dataset's intrinsics), planner/goal,
       sim/status, sim/frame_ack (the sources' acknowledgements), sim/voxel_map (MEGA-DAgger), each expert's
       plan (expert_topics), the learner's plan (learner_topic)
  out  tracker/track_bspline (action goal: the plan of whoever flies), ~executed (quad_msgs/Bspline),
       sim/frame_ack (as consumer_name, after each decision: in lockstep the simulator waits for it)
Parameters: ~round_config (the manager's round_XXX/algorithm.yaml), ~output_dir, ~episodes (stop after N
  episodes that received a goal), all required; the rest come from config/imitation_collector.yaml (every key
  documented there), each overridable by a private parameter of the same name.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import actionlib
import numpy as np
import rospy
from geometry_msgs.msg import Point, PoseStamped
from nav_msgs.msg import Odometry
from sensor_msgs import point_cloud2
from sensor_msgs.msg import CameraInfo, Image, PointCloud2

from quad_il.imitation.bspline import SplineAction
from quad_il.imitation.collector_config import KEYS, load_collector_node_config, shipped_config_path
from quad_il.imitation.collector_core import (
    AckBook,
    CollectorCore,
    CollectorCounters,
    EpisodeBook,
    HeldFrames,
    OdometryBuffer,
    TimingLog,
    collector_manifest,
    expert_noise_from_param,
    load_round_config,
    mega_clearance,
    perturb_spline,
    write_json_atomic,
)
from quad_il.imitation.learners import make_learner
from quad_il.imitation.messages import observation_from_msgs, spline_from_msg
from quad_il.imitation.pairing import PairedFrame, stamp_key
from quad_il.imitation.safety import PointCloudClearance
from quad_il.imitation.types import Controller, EpisodeOutcome, ImitationError
from quad_il.ros_params import require_param
from quad_il.tools.provenance import git_commit
from quad_msgs.msg import Bspline, EpisodeStatus, FrameAck, TrackBsplineAction, TrackBsplineGoal

COMMAND_LINE = "the collector command of the manager config (or the launch/test file starting the node)"


def ros_time(stamp_s: float) -> rospy.Time:
    """Exactly the nanoseconds of the original stamp (rospy.Time.from_sec truncates: 1.005 -> 1.004999999)."""
    k = stamp_key(stamp_s)
    return rospy.Time(k // 1_000_000_000, k % 1_000_000_000)


class CollectorNode:
    def __init__(self) -> None:
        self.cfg = load_round_config(require_param("~round_config", COMMAND_LINE))
        self.output_dir = Path(require_param("~output_dir", COMMAND_LINE))
        self.output_dir.mkdir(parents=True, exist_ok=True)
        self.max_episodes = int(require_param("~episodes", COMMAND_LINE))
        overrides = {k: rospy.get_param(f"~{k}") for k in KEYS if rospy.has_param(f"~{k}")}
        self.p = p = load_collector_node_config(shipped_config_path(), overrides)
        self.expert_noise = expert_noise_from_param(p.expert_noise_std_m, p.expert_topics)
        self.noise_rng = np.random.default_rng([self.cfg.seed, self.cfg.round_index, 1])
        self.clearance = mega_clearance(self.cfg, p.expert_topics)  # swapped in by on_voxel_map
        self.learner = make_learner(self.cfg, np.random.default_rng(self.cfg.seed), self.clearance)
        experts = list(p.expert_topics)
        self.sources = experts if self.cfg.expert_only else [*experts, "learner"]
        self.consumer_source = {p.source_consumers[s]: s for s in self.sources if s in p.source_consumers}
        run_info = {"round_index": str(self.cfg.round_index), "algorithm": self.cfg.algorithm.name}
        commit = git_commit()["commit"]
        self.core = CollectorCore(
            self.learner, self.sources, experts[0], self.output_dir, run_info, software_commit=commit
        )
        self.camera: dict[str, float] = {}  # the dataset's intrinsics, from camera_info
        self.book = EpisodeBook()
        self.acks = AckBook(self.sources)
        self.counters = CollectorCounters()
        self.odom = OdometryBuffer[Odometry](p.odom_period_s, p.odom_wait_s, self.counters)
        self.held = HeldFrames(p.pair_timeout_s, time.monotonic)
        self.state = {"interrupted": False, "done": False}
        self.timing = TimingLog(p.timing_log) if p.timing_log else None
        # rospy runs each subscription's callbacks in its own thread: one lock serialises the core.
        self.lock = threading.RLock()
        self.tracker = actionlib.ActionClient("tracker/track_bspline", TrackBsplineAction)
        self.handles: list[Any] = []  # goals kept tracked until done (an untracked handle's transitions err)
        self.handles_lock = threading.Lock()
        self.executed_pub = rospy.Publisher("~executed", Bspline, queue_size=10)
        self.ack_pub = rospy.Publisher("sim/frame_ack", FrameAck, queue_size=100, tcp_nodelay=True)

    # ---- outputs ----
    def ack(self, stamp_s: float, seq: int) -> None:
        self.ack_pub.publish(FrameAck(consumer=self.p.consumer_name, frame_seq=seq, stamp=ros_time(stamp_s)))

    def send(self, action: SplineAction) -> None:
        msg = Bspline(
            order=action.order,
            traj_id=action.traj_id,
            start_time=ros_time(action.start_time_s),
            knots=action.knots.tolist(),
        )
        msg.pos_pts = [Point(float(q[0]), float(q[1]), float(q[2])) for q in action.ctrl_pts_world]
        gh = self.tracker.send_goal(TrackBsplineGoal(bspline=msg), transition_cb=self.on_transition)
        with self.handles_lock:
            self.handles.append(gh)
        self.executed_pub.publish(msg)
        # Lockstep: the tracker takes the trajectory before the frame is acknowledged (bounded wall wait).
        deadline = time.monotonic() + self.p.tracker_accept_timeout_s
        waiting = (actionlib.CommState.WAITING_FOR_GOAL_ACK, actionlib.CommState.PENDING)
        while gh.get_comm_state() in waiting:
            if time.monotonic() > deadline or rospy.is_shutdown():
                self.counters.tracker_accept_timeouts += 1
                break
            time.sleep(0.0005)

    def on_transition(self, gh: Any) -> None:
        if gh.get_comm_state() != actionlib.CommState.DONE:
            return
        if gh.get_terminal_state() == actionlib.GoalStatus.REJECTED:
            self.counters.tracker_rejections += 1
        with self.handles_lock:  # not the core's lock: send() holds that while it waits for this callback
            if gh in self.handles:
                self.handles.remove(gh)

    def act(self, frames: list[PairedFrame]) -> None:
        for frame, decision in self.core.frames(frames):
            self.held.release(frame.obs.stamp_s)
            if decision.controller is not Controller.NONE and decision.action is not None:
                self.send(decision.action)
            self.ack(frame.obs.stamp_s, frame.obs.frame_seq)

    # ---- completing frames whose plans will not come ----
    def complete_missing(self, stamp_s: float) -> None:
        """Sources that acknowledged this frame and whose plan is still missing after the grace: None."""
        for s in self.sources:
            if self.acks.acked(s, stamp_s) and self.core.pairer.waiting_for(s, stamp_s):
                self.counters.acked_without_plan += 1
                self.act(self.core.pairer.add_action(s, stamp_s, None))

    def schedule(self, stamp_s: float) -> None:
        def fire() -> None:
            with self.lock:
                self.complete_missing(stamp_s)

        timer = threading.Timer(self.p.ack_grace_s, fire)
        timer.daemon = True
        timer.start()

    def watchdog(self) -> None:
        while not rospy.is_shutdown():
            time.sleep(0.05)
            with self.lock:
                for t in self.held.expired():
                    self.counters.pair_timeouts += 1
                    for s in self.sources:
                        if self.core.pairer.waiting_for(s, t):
                            self.act(self.core.pairer.add_action(s, t, None))

    # ---- callbacks ----
    def on_camera_info(self, msg: CameraInfo) -> None:
        k = msg.K
        with self.lock:
            self.camera = {
                "camera_fx_px": k[0],
                "camera_fy_px": k[4],
                "camera_cx_px": k[2],
                "camera_cy_px": k[5],
            }

    def on_odom(self, msg: Odometry) -> None:
        self.odom.add(msg.header.stamp.to_sec(), msg)

    def on_goal(self, msg: PoseStamped) -> None:
        g = msg.pose.position
        with self.lock:
            if self.book.set_goal(msg.header.stamp.to_sec(), np.array([g.x, g.y, g.z])):
                rospy.loginfo(f"imitation_collector: goal ({g.x:.2f}, {g.y:.2f}, {g.z:.2f})")

    def on_depth(self, msg: Image) -> None:
        t = msg.header.stamp.to_sec()
        with self.lock:
            flying = not self.state["done"] and self.book.flying
        found = self.odom.for_frame(t) if flying else None  # outside the lock: it may wait
        with self.lock:
            if not flying or found is None or not self.book.flying:
                self.ack(t, msg.header.seq)  # outside an episode, before its goal, or no odometry: unpaired
                return
            o, latest = found
            if self.timing is not None:
                delay = (rospy.Time.now() - msg.header.stamp).to_sec()
                self.timing.row(t, o.header.stamp.to_sec(), latest.header.stamp.to_sec(), delay)
            try:
                obs = observation_from_msgs(msg, o, self.book.episode_id, self.book.goal)
            except ImitationError as e:
                rospy.logwarn_throttle(5.0, f"imitation_collector: depth frame at {t:.3f} s rejected: {e}")
                self.ack(t, msg.header.seq)
                return
            self.held.hold(t)
            self.act(self.core.pairer.add_observation(obs))
            if self.acks.any_acked(t):
                self.schedule(t)

    def on_plan(self, msg: Bspline, source: str) -> None:
        t = msg.start_time.to_sec()
        try:
            action = spline_from_msg(msg)
        except ValueError as e:
            rospy.logwarn_throttle(5.0, f"imitation_collector: {source} plan rejected: {e}")
            action = None
        with self.lock:
            if not self.core.pairer.waiting_for(source, t):
                self.counters.unpaired_plans += 1  # its frame was skipped (no goal yet) or completed
                return
            if action is not None and self.expert_noise.get(source, 0.0) > 0.0:
                # under the lock: the generator is shared by the experts' subscriber threads
                action = perturb_spline(action, self.expert_noise[source], self.noise_rng)
            self.act(self.core.pairer.add_action(source, t, action))

    def on_ack(self, msg: FrameAck) -> None:
        s = self.consumer_source.get(msg.consumer)
        if s is None:
            return
        t = msg.stamp.to_sec()
        with self.lock:
            self.acks.add(s, t)
            if self.core.pairer.waiting_for(s, t):
                self.schedule(t)

    def end_episode(self, eid: int, flown: bool, msg: EpisodeStatus) -> None:
        self.act(self.core.pairer.flush_all())  # frames still held belong to this episode
        same = int(msg.episode_id) == eid
        outcome = EpisodeOutcome(
            reached_goal=bool(msg.reached_goal) and same,
            collided=bool(msg.collided) and same,
            collision_time_s=msg.collision_time.to_sec() if (msg.collided and same) else None,
            reason=msg.reason if same else "next episode started",
        )
        seed = self.book.world_seeds.get(eid, 0)
        self.core.finish_episode(eid, outcome, flown=flown, world_seed=seed, **self.camera)
        if self.core.write_error:
            rospy.logerr_once(f"imitation_collector: {self.core.write_error}")
        rospy.loginfo(
            f"imitation_collector: episode {eid} done ({outcome.reason}); {self.core.episodes_flown}/"
            f"{self.max_episodes} episodes flown, {self.core.records_written} records"
        )
        if self.core.episodes_flown >= self.max_episodes and not self.state["done"]:
            self.state["done"] = True
            rospy.signal_shutdown("episodes done")

    def on_status(self, msg: EpisodeStatus) -> None:
        with self.lock:
            for kind, eid, flown in self.book.status(
                int(msg.episode_id), bool(msg.active), msg.header.stamp.to_sec(), int(msg.world_seed)
            ):
                if kind == "end":
                    if self.learner.episode_id is not None:
                        self.end_episode(eid, flown, msg)
                elif not self.state["done"]:
                    self.learner.start_episode(eid)

    def on_voxel_map(self, msg: PointCloud2) -> None:
        # outside the lock: building the map takes a while
        pts = np.array(list(point_cloud2.read_points(msg, field_names=("x", "y", "z"), skip_nans=True)))
        fresh = PointCloudClearance(pts.reshape(-1, 3), self.p.voxel_size_m)
        with self.lock:
            if self.clearance is not None:
                self.clearance.update(fresh)

    def finalise(self) -> None:
        # SIGINT (rospy's handler) and normal ends both land here: close the open episode, write the manifest.
        with self.lock:
            if self.book.episode_id is not None and self.learner.episode_id is not None:
                self.state["interrupted"] = not self.state["done"]
                eid = self.book.episode_id
                self.core.finish_episode(
                    eid,
                    EpisodeOutcome(reason="collector stopped"),
                    flown=self.book.had_goal,
                    world_seed=self.book.world_seeds.get(eid, 0),
                    **self.camera,
                )
                self.book.episode_id = None
            if not self.core.finalize() and not self.core.write_error:
                self.core.write_error = "the dataset could not be finalised (manifest.yaml: writer_error)"
                rospy.logerr(f"imitation_collector: {self.core.write_error}")
            if self.timing is not None:
                self.timing.close()
            if self.clearance is not None:
                self.counters.voxel_maps = self.clearance.updates
                self.counters.label_checks_without_map = self.clearance.queries_without_map
            write_json_atomic(
                self.output_dir / "collector_manifest.json",
                collector_manifest(self.cfg, self.core, self.state["interrupted"], self.counters),
            )

    def subscribe(self) -> None:
        rospy.on_shutdown(self.finalise)
        if self.clearance is not None:
            rospy.Subscriber("sim/voxel_map", PointCloud2, self.on_voxel_map, queue_size=1, buff_size=2**24)
        rospy.Subscriber("odom", Odometry, self.on_odom, queue_size=400, tcp_nodelay=True)
        rospy.Subscriber("camera/depth/camera_info", CameraInfo, self.on_camera_info, queue_size=1)
        rospy.Subscriber("planner/goal", PoseStamped, self.on_goal, queue_size=5)
        rospy.Subscriber("sim/status", EpisodeStatus, self.on_status, queue_size=20)
        rospy.Subscriber("sim/frame_ack", FrameAck, self.on_ack, queue_size=200, tcp_nodelay=True)
        plan_topics = dict(self.p.expert_topics)
        if not self.cfg.expert_only:
            plan_topics["learner"] = self.p.learner_topic
        for name, topic in plan_topics.items():
            rospy.Subscriber(
                topic, Bspline, self.on_plan, callback_args=name, queue_size=20, tcp_nodelay=True
            )
        rospy.Subscriber(
            "camera/depth/image", Image, self.on_depth, queue_size=5, buff_size=2**24, tcp_nodelay=True
        )
        threading.Thread(target=self.watchdog, daemon=True).start()


def main() -> int:  # pragma: no cover - needs a ROS master; tests/rostest/il_dagger_round.test
    rospy.init_node("imitation_collector")
    try:
        node = CollectorNode()
    except (ImitationError, KeyError, OSError, ValueError) as e:
        rospy.logfatal(f"imitation_collector: {e}")
        return 2
    node.subscribe()
    rospy.loginfo(
        f"imitation_collector: {node.cfg.algorithm.name} round {node.cfg.round_index}, sources "
        f"{node.sources}, {node.max_episodes} episodes -> {node.output_dir}"
    )
    rospy.spin()
    return 0
