"""rospy adapter of the interactive collector (thin): `src/quad_il/nodes/imitation_collector.py`.

The decision logic it wraps (`learners`, `pairing`, `dataset`) is ROS-free; this module converts messages,
runs the callbacks, forwards the chosen plan to the tracker, acknowledges frames and writes episode files.
rospy and the message packages are imported inside `main()`, so importing this module needs no ROS. Tested
without ROS: message conversion, `CollectorCore` and `EpisodeBook`
(tests/python/test_imitation_collector_core.py); with ROS: tests/rostest/il_dagger_round.test (one DAgger
round, learner flying, expert labelling).

Topics (private parameters in brackets):
  in   /odom, /camera/depth/image (32FC1), /planner/goal, /sim/status, /sim/frame_ack (the sources'
       acknowledgements), /sim/voxel_map (MEGA-DAgger), each expert's plan [~expert_topics: {name: topic},
       default {expert: /expert/bspline}], the learner's plan [~learner_topic, default /learner/bspline]
  out  /tracker/track_bspline (action goal: the plan of whoever flies), ~executed (quad_msgs/Bspline),
       /sim/frame_ack (consumer [~consumer_name], after each decision: in lockstep the simulator waits for it,
       so the decision is applied before time advances)
Parameters: ~round_config (the manager's round_XXX/algorithm.yaml), ~output_dir, ~episodes (stop after N
  episodes that received a goal), ~voxel_size_m (MEGA-DAgger's clearance map), ~source_consumers ({source:
  FrameAck consumer}, default {expert: fast_planner, learner: policy}), ~expert_noise_std_m ({expert: std in
  metres}, default {}: Gaussian noise on an expert's control points, making it one of MEGA-DAgger's imperfect
  experts; `perturb_spline`), ~ack_grace_s (0.25), ~pair_timeout_s
  (5.0), ~tracker_accept_timeout_s (1.0), ~odom_period_s (0.005), ~odom_wait_s (0.5: wait this long for the
  frame's odometry; 0: take the newest that has arrived), ~timing_log (CSV: depth stamp, odometry used, newest
  odometry received, clock delay; "" = none).

The state of an observation is the newest odometry stamped at or before the frame. Odometry and depth arrive
on different connections and rospy threads, so the frame's odometry may not have arrived when the frame does
(measured in lockstep: up to 37 ms old without the wait); the collector waits for it (~odom_wait_s).

Pairing in lockstep: every plan carries the stamp of the depth frame it was planned from as `start_time`. A
source that has no plan for a frame (the labeller found no path, the policy has no goal yet) says so by
acknowledging the frame without publishing a plan (the labeller also publishes an empty B-spline); the
frame is
completed with None for that source once its acknowledgement is in and `ack_grace_s` has passed without a plan
(plans and acknowledgements travel on different connections). `pair_timeout_s` completes a frame whose source
went silent. Frames outside an episode or before the episode's goal are acknowledged at once, unpaired.
"""

from __future__ import annotations

import json
import math
import os
import tempfile
import threading
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from quad_il.imitation.bspline import SplineAction
from quad_il.imitation.config import MegaDAggerConfig, RoundAlgorithmConfig
from quad_il.imitation.dataset import write_episode
from quad_il.imitation.learners import ImitationLearnerBase, make_learner
from quad_il.imitation.pairing import PairedFrame, StampPairer
from quad_il.imitation.safety import PointCloudClearance, WorldClearance
from quad_il.imitation.types import Controller, EpisodeOutcome, ImitationError, Observation, Pair, Record


def load_round_config(path: str | Path) -> RoundAlgorithmConfig:
    with open(path) as fh:
        return RoundAlgorithmConfig.model_validate(yaml.safe_load(fh))


def spline_from_msg(msg: Any) -> SplineAction | None:
    """A quad_msgs/Bspline -> SplineAction; None for an empty message (a source saying "no plan for this
    frame"); ValueError for a malformed one."""
    if len(msg.pos_pts) == 0:
        return None
    ctrl = np.array([[p.x, p.y, p.z] for p in msg.pos_pts], dtype=np.float64).reshape(-1, 3)
    return SplineAction(
        ctrl,
        np.asarray(msg.knots, dtype=np.float64),
        int(msg.order),
        msg.start_time.to_sec(),
        int(msg.traj_id),
    )


def perturb_spline(action: SplineAction, std_m: float, rng: np.random.Generator) -> SplineAction:
    """An imperfect expert for MEGA-DAgger (`~expert_noise_std_m`): independent Gaussian noise of `std_m`
    metres on every control point except the first `order` ones, which fix the plan's start state (position,
    velocity, acceleration at the frame), so the noisy plan still starts where the vehicle is."""
    if not np.isfinite(std_m) or std_m < 0.0:
        raise ImitationError(f"expert noise std must be a finite number >= 0 m, got {std_m}")
    ctrl = action.ctrl_pts_world.copy()
    keep = min(int(action.order), len(ctrl))
    ctrl[keep:] += rng.normal(0.0, std_m, size=ctrl[keep:].shape)
    return SplineAction(ctrl, action.knots, action.order, action.start_time_s, action.traj_id)


def expert_noise_from_param(value: Any, expert_topics: dict[str, str]) -> dict[str, float]:
    """`~expert_noise_std_m` checked: a mapping from expert names of `~expert_topics` to standard deviations
    (metres, finite, >= 0)."""
    if not isinstance(value, dict):
        raise ImitationError(f"~expert_noise_std_m must be a mapping {{expert: metres}}, got {value!r}")
    out = {}
    for name, std in value.items():
        if name not in expert_topics:
            raise ImitationError(
                f"~expert_noise_std_m names {name!r}, which is not in ~expert_topics {sorted(expert_topics)}"
            )
        try:
            out[str(name)] = float(std)
        except (TypeError, ValueError):
            raise ImitationError(
                f"~expert_noise_std_m[{name!r}] must be a number of metres, got {std!r}"
            ) from None
        if not math.isfinite(out[str(name)]) or out[str(name)] < 0.0:
            raise ImitationError(f"~expert_noise_std_m[{name!r}] must be finite and >= 0 m, got {std!r}")
    return out


def depth_from_msg(msg: Any) -> np.ndarray:
    if msg.encoding != "32FC1":
        raise ImitationError(f"depth image encoding must be 32FC1, got {msg.encoding!r}")
    row = np.frombuffer(bytes(msg.data), dtype=np.float32 if not msg.is_bigendian else ">f4")
    return row.reshape(msg.height, msg.step // 4)[:, : msg.width].astype(np.float32)


def write_json_atomic(path: Path, payload: dict[str, Any]) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    with os.fdopen(fd, "w") as fh:
        json.dump(payload, fh, indent=2, sort_keys=True)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


class CollectorCore:
    """ROS-agnostic glue between pairer, learner and writer (the node feeds it converted messages)."""

    def __init__(
        self, learner: ImitationLearnerBase, sources: list[str], primary: str, output_dir: Path
    ) -> None:
        self.learner = learner
        self.primary = primary
        self.experts = [s for s in sources if s != "learner"]
        self.pairer = StampPairer(sources)
        self.output_dir = output_dir
        self.episode_records: list[Record] = []
        self.episodes_written = 0  # episodes closed (with or without records)
        self.episodes_flown = 0  # closed episodes that had a goal
        self.files_written = 0
        self.records_written = 0

    def frames(self, frames: list[PairedFrame]) -> list[tuple[PairedFrame, Any]]:
        out = []
        for f in frames:
            pair = Pair(
                obs=f.obs,
                learner=f.actions.get("learner"),
                experts={e: f.actions.get(e) for e in self.experts},
                primary_expert=self.primary,
            )
            decision = self.learner.step(pair)
            self.episode_records.extend(decision.records)
            out.append((f, decision))
        return out

    def finish_episode(self, episode_id: int, outcome: EpisodeOutcome, flown: bool = True) -> None:
        self.episode_records.extend(self.learner.end_episode(outcome))
        if self.episode_records:
            write_episode(self.output_dir, episode_id, self.episode_records)
            self.records_written += len(self.episode_records)
            self.files_written += 1
        self.episode_records = []
        self.episodes_written += 1
        self.episodes_flown += int(flown)


class EpisodeBook:
    """Which episode is open and whether its goal is known, from /sim/status and /planner/goal (ROS-free).

    `status()` returns the transitions to apply, in order: ("end", old_id, flown) and/or ("start", new_id,
    False). A goal
    counts for the open episode only if it is stamped at or after the episode's first status (the goal topic
    is latched: the previous episode's goal is delivered again to late subscribers). An episode is "flown"
    once
    it received its goal."""

    def __init__(self) -> None:
        self.episode_id: int | None = None
        self.start_s = 0.0
        self.goal: np.ndarray | None = None
        self.had_goal = False
        self.ended: set[int] = set()

    def status(self, episode_id: int, active: bool, stamp_s: float) -> list[tuple[str, int, bool]]:
        """Transitions ("end", id, flown) and/or ("start", id, False), in this order."""
        out: list[tuple[str, int, bool]] = []
        if self.episode_id is not None and (episode_id != self.episode_id or not active):
            out.append(("end", self.episode_id, self.had_goal))
            self.ended.add(self.episode_id)
            self.episode_id, self.goal = None, None
        if self.episode_id is None and active and episode_id not in self.ended:
            self.episode_id, self.start_s, self.goal, self.had_goal = (
                int(episode_id),
                float(stamp_s),
                None,
                False,
            )
            out.append(("start", self.episode_id, False))
        return out

    def set_goal(self, stamp_s: float, goal: np.ndarray) -> bool:
        if self.episode_id is None or stamp_s < self.start_s - 1e-9:
            return False
        self.goal = np.asarray(goal, dtype=np.float64)
        self.had_goal = True
        return True

    @property
    def flying(self) -> bool:
        return self.episode_id is not None and self.goal is not None


def _key(stamp_s: float) -> int:
    return int(round(stamp_s * 1e9))


def main() -> None:  # pragma: no cover - needs a ROS master; tests/rostest/il_dagger_round.test
    import csv
    import time

    import actionlib
    import rospy
    from geometry_msgs.msg import Point, PoseStamped
    from nav_msgs.msg import Odometry
    from sensor_msgs import point_cloud2
    from sensor_msgs.msg import Image, PointCloud2

    from quad_msgs.msg import Bspline, EpisodeStatus, FrameAck, TrackBsplineAction, TrackBsplineGoal

    rospy.init_node("imitation_collector")
    cfg = load_round_config(rospy.get_param("~round_config"))
    output_dir = Path(rospy.get_param("~output_dir"))
    output_dir.mkdir(parents=True, exist_ok=True)
    max_episodes = int(rospy.get_param("~episodes", 10))
    consumer = str(rospy.get_param("~consumer_name", "imitation_collector"))
    expert_topics: dict[str, str] = dict(rospy.get_param("~expert_topics", {"expert": "/expert/bspline"}))
    source_consumers: dict[str, str] = dict(
        rospy.get_param("~source_consumers", {"expert": "fast_planner", "learner": "policy"})
    )
    expert_noise = expert_noise_from_param(rospy.get_param("~expert_noise_std_m", {}), expert_topics)
    noise_rng = np.random.default_rng([cfg.seed, cfg.round_index, 1])
    ack_grace_s = float(rospy.get_param("~ack_grace_s", 0.25))
    pair_timeout_s = float(rospy.get_param("~pair_timeout_s", 5.0))
    accept_timeout_s = float(rospy.get_param("~tracker_accept_timeout_s", 1.0))
    timing_path = str(rospy.get_param("~timing_log", ""))
    odom_period_s = float(rospy.get_param("~odom_period_s", 0.005))
    odom_wait_s = float(rospy.get_param("~odom_wait_s", 0.5))
    if isinstance(cfg.algorithm, MegaDAggerConfig):
        missing = [e for e in cfg.algorithm.experts if e not in expert_topics]
        if missing:
            raise ImitationError(f"~expert_topics lacks the MEGA-DAgger experts {missing}")
    primary = next(iter(expert_topics))
    clearance: WorldClearance | None = None
    voxel_size_m = float(rospy.get_param("~voxel_size_m", 0.1))

    def clearance_from_cloud(cloud: Any) -> PointCloudClearance:
        pts = np.array(list(point_cloud2.read_points(cloud, field_names=("x", "y", "z"), skip_nans=True)))
        return PointCloudClearance(pts.reshape(-1, 3), voxel_size_m)

    if isinstance(cfg.algorithm, MegaDAggerConfig):
        # The simulator publishes (latched) the voxel map of each world at its reset, before the episode's
        # goal; on_voxel_map swaps it in. (Not waited for here: in lockstep the simulator starts only once
        # this node subscribes to depth.)
        clearance = WorldClearance()
    learner = make_learner(cfg, np.random.default_rng(cfg.seed), clearance)
    sources = [*expert_topics, "learner"] if not cfg.expert_only else list(expert_topics)
    consumer_source = {source_consumers[s]: s for s in sources if s in source_consumers}
    core = CollectorCore(learner, sources, primary, output_dir)
    book = EpisodeBook()

    tracker = actionlib.ActionClient("/tracker/track_bspline", TrackBsplineAction)
    handles: list[Any] = []  # goals kept tracked until done (an untracked handle's transitions are errors)
    handles_lock = threading.Lock()
    executed_pub = rospy.Publisher("~executed", Bspline, queue_size=10)
    ack_pub = rospy.Publisher("/sim/frame_ack", FrameAck, queue_size=100, tcp_nodelay=True)
    odom_buf: list[Any] = []
    acked: dict[str, dict[int, float]] = {s: {} for s in sources}  # source -> {stamp key: stamp}
    arrivals: dict[int, float] = {}  # stamp key of a held frame -> wall time its observation arrived
    counters = {
        "odom_waits": 0,
        "odom_wait_timeouts": 0,
        "tracker_rejections": 0,
        "unpaired_plans": 0,
        "pair_timeouts": 0,
        "acked_without_plan": 0,
        "tracker_accept_timeouts": 0,
        "voxel_maps": 0,
        "label_checks_without_map": 0,
    }
    state: dict[str, Any] = {"interrupted": False, "done": False}
    timing_fh = open(timing_path, "w", newline="") if timing_path else None  # noqa: SIM115
    timing = csv.writer(timing_fh) if timing_fh else None
    if timing is not None:
        timing.writerow(["depth_stamp_s", "odom_used_stamp_s", "odom_latest_stamp_s", "clock_delay_s"])
    # rospy runs each subscription's callbacks in its own thread: one lock serialises the core.
    lock = threading.RLock()

    def ros_time(stamp_s: float) -> Any:
        # Exactly the nanoseconds of the original stamp (rospy.Time.from_sec truncates: 1.005 -> 1.004999999).
        k = _key(stamp_s)
        return rospy.Time(k // 1_000_000_000, k % 1_000_000_000)

    def ack(stamp_s: float, seq: int) -> None:
        ack_pub.publish(FrameAck(consumer=consumer, frame_seq=seq, stamp=ros_time(stamp_s)))

    def send(action: SplineAction) -> None:
        msg = Bspline(
            order=action.order,
            traj_id=action.traj_id,
            start_time=ros_time(action.start_time_s),
            knots=action.knots.tolist(),
        )
        msg.pos_pts = [Point(float(p[0]), float(p[1]), float(p[2])) for p in action.ctrl_pts_world]
        gh = tracker.send_goal(TrackBsplineGoal(bspline=msg), transition_cb=on_transition)
        with handles_lock:
            handles.append(gh)
        executed_pub.publish(msg)
        # Lockstep: the tracker takes the trajectory before the frame is acknowledged (bounded wall wait).
        deadline = time.monotonic() + accept_timeout_s
        waiting = (actionlib.CommState.WAITING_FOR_GOAL_ACK, actionlib.CommState.PENDING)
        while gh.get_comm_state() in waiting:
            if time.monotonic() > deadline or rospy.is_shutdown():
                counters["tracker_accept_timeouts"] += 1
                break
            time.sleep(0.0005)

    def on_transition(gh: Any) -> None:
        if gh.get_comm_state() != actionlib.CommState.DONE:
            return
        if gh.get_terminal_state() == actionlib.GoalStatus.REJECTED:
            counters["tracker_rejections"] += 1
        with handles_lock:  # not the core's lock: send() holds that while it waits for this callback's state
            if gh in handles:
                handles.remove(gh)

    def act(frames: list[PairedFrame]) -> None:
        for frame, decision in core.frames(frames):
            arrivals.pop(_key(frame.obs.stamp_s), None)
            if decision.controller is not Controller.NONE and decision.action is not None:
                send(decision.action)
            ack(frame.obs.stamp_s, frame.obs.frame_seq)

    def complete_missing(stamp_s: float) -> None:
        """Sources that acknowledged this frame and whose plan is still missing after the grace: None."""
        key = _key(stamp_s)
        for s in sources:
            if key in acked[s] and core.pairer.waiting_for(s, stamp_s):
                counters["acked_without_plan"] += 1
                act(core.pairer.add_action(s, stamp_s, None))

    def schedule(stamp_s: float) -> None:
        def fire() -> None:
            with lock:
                complete_missing(stamp_s)

        timer = threading.Timer(ack_grace_s, fire)
        timer.daemon = True
        timer.start()

    odom_cv = threading.Condition()  # guards odom_buf (not the core's lock: frames wait on it)

    def on_odom(msg: Any) -> None:
        with odom_cv:
            odom_buf.append(msg)
            del odom_buf[:-400]
            odom_cv.notify_all()

    def odometry_for(t: float) -> tuple[Any, Any] | None:
        """(newest odometry stamped at or before t, newest received). Odometry and depth arrive on different
        connections and threads: the frame's odometry (stamped within one period before it, published before
        it) may still be on its way. Wait for it up to ~odom_wait_s (0: take what has arrived, as a naive
        collector would)."""
        with odom_cv:

            def arrived() -> bool:
                return bool(odom_buf) and odom_buf[-1].header.stamp.to_sec() > t - odom_period_s + 1e-6

            if odom_wait_s > 0.0 and not arrived():
                counters["odom_waits"] += 1
                if not odom_cv.wait_for(arrived, timeout=odom_wait_s):
                    counters["odom_wait_timeouts"] += 1
            older = [o for o in odom_buf if o.header.stamp.to_sec() <= t + 1e-9]
            return (older[-1], odom_buf[-1]) if older else None

    def on_goal(msg: Any) -> None:
        p = msg.pose.position
        with lock:
            if book.set_goal(msg.header.stamp.to_sec(), np.array([p.x, p.y, p.z])):
                rospy.loginfo(f"imitation_collector: goal ({p.x:.2f}, {p.y:.2f}, {p.z:.2f})")

    def on_depth(msg: Any) -> None:
        t = msg.header.stamp.to_sec()
        with lock:
            flying = not state["done"] and book.flying
        found = odometry_for(t) if flying else None
        with lock:
            if not flying or found is None or not book.flying:
                ack(t, msg.header.seq)  # outside an episode, before its goal, or no odometry: nothing to pair
                return
            o, latest = found
            if timing is not None:
                timing.writerow(
                    [
                        f"{t:.9f}",
                        f"{o.header.stamp.to_sec():.9f}",
                        f"{latest.header.stamp.to_sec():.9f}",
                        f"{(rospy.Time.now() - msg.header.stamp).to_sec():.6f}",
                    ]
                )
            pose, twist = o.pose.pose, o.twist.twist
            try:
                obs = Observation(
                    stamp_s=t,
                    frame_seq=msg.header.seq,
                    episode_id=book.episode_id,
                    p_world_body=[pose.position.x, pose.position.y, pose.position.z],
                    v_world=[twist.linear.x, twist.linear.y, twist.linear.z],
                    q_world_body=[
                        pose.orientation.x,
                        pose.orientation.y,
                        pose.orientation.z,
                        pose.orientation.w,
                    ],
                    goal_world=book.goal,
                    depth_m=depth_from_msg(msg),
                    odom_stamp_s=o.header.stamp.to_sec(),
                )
            except ImitationError as e:
                rospy.logwarn_throttle(5.0, f"imitation_collector: depth frame at {t:.3f} s rejected: {e}")
                ack(t, msg.header.seq)
                return
            arrivals[_key(t)] = time.monotonic()
            act(core.pairer.add_observation(obs))
            if any(_key(t) in acked[s] for s in sources):
                schedule(t)

    def on_plan(source: str) -> Any:
        def cb(msg: Any) -> None:
            t = msg.start_time.to_sec()
            try:
                action = spline_from_msg(msg)
            except ValueError as e:
                rospy.logwarn_throttle(5.0, f"imitation_collector: {source} plan rejected: {e}")
                action = None
            with lock:
                if not core.pairer.waiting_for(source, t):
                    counters["unpaired_plans"] += 1  # its frame was skipped (no goal yet) or completed
                    return
                if action is not None and expert_noise.get(source, 0.0) > 0.0:
                    # under the lock: the generator is shared by the experts' subscriber threads
                    action = perturb_spline(action, expert_noise[source], noise_rng)
                act(core.pairer.add_action(source, t, action))

        return cb

    def on_ack(msg: Any) -> None:
        s = consumer_source.get(msg.consumer)
        if s is None:
            return
        t = msg.stamp.to_sec()
        with lock:
            d = acked[s]
            d[_key(t)] = t
            if len(d) > 256:
                for k in sorted(d)[:128]:
                    del d[k]
            if core.pairer.waiting_for(s, t):
                schedule(t)

    def end_episode(eid: int, flown: bool, msg: Any) -> None:
        # Frames still held belong to this episode: complete them first.
        act(core.pairer.flush_all())
        same = int(msg.episode_id) == eid
        outcome = EpisodeOutcome(
            reached_goal=bool(msg.reached_goal) and same,
            collided=bool(msg.collided) and same,
            collision_time_s=msg.collision_time.to_sec() if (msg.collided and same) else None,
            reason=msg.reason if same else "next episode started",
        )
        core.finish_episode(eid, outcome, flown=flown)
        rospy.loginfo(
            f"imitation_collector: episode {eid} done ({outcome.reason}); "
            f"{core.episodes_flown}/{max_episodes}"
            f" episodes flown, {core.records_written} records"
        )
        if core.episodes_flown >= max_episodes and not state["done"]:
            state["done"] = True
            rospy.signal_shutdown("episodes done")

    def on_status(msg: Any) -> None:
        with lock:
            for kind, eid, flown in book.status(
                int(msg.episode_id), bool(msg.active), msg.header.stamp.to_sec()
            ):
                if kind == "end":
                    if learner.episode_id is not None:
                        end_episode(eid, flown, msg)
                elif not state["done"]:
                    learner.start_episode(eid)

    def watchdog() -> None:
        while not rospy.is_shutdown():
            time.sleep(0.05)
            with lock:
                now = time.monotonic()
                for k in sorted(k for k, t0 in arrivals.items() if now - t0 > pair_timeout_s):
                    arrivals.pop(k, None)
                    counters["pair_timeouts"] += 1
                    for s in sources:
                        if core.pairer.waiting_for(s, k * 1e-9):
                            act(core.pairer.add_action(s, k * 1e-9, None))

    def finalise() -> None:
        # SIGINT (rospy's handler) and normal ends both land here: close the open episode, write the manifest.
        with lock:
            if book.episode_id is not None and learner.episode_id is not None:
                state["interrupted"] = not state["done"]
                core.finish_episode(
                    book.episode_id, EpisodeOutcome(reason="collector stopped"), flown=book.had_goal
                )
                book.episode_id = None
            if timing_fh is not None:
                timing_fh.close()
            if clearance is not None:
                counters["voxel_maps"] = clearance.updates
                counters["label_checks_without_map"] = clearance.queries_without_map
            write_json_atomic(
                output_dir / "collector_manifest.json",
                {
                    "round_config": cfg.model_dump(mode="json"),
                    "episodes": core.episodes_flown,
                    "episodes_closed": core.episodes_written,
                    "files": core.files_written,
                    "records": core.records_written,
                    "interrupted": state["interrupted"],
                    "stats": vars(learner.stats),
                    "algorithm_stats": learner.algorithm_stats(),
                    "pairer": vars(core.pairer.stats),
                    "collector": counters,
                },
            )

    def on_voxel_map(msg: Any) -> None:
        fresh = clearance_from_cloud(msg)  # outside the lock: building the map takes a while
        with lock:
            if clearance is not None:
                clearance.update(fresh)

    rospy.on_shutdown(finalise)
    if clearance is not None:
        rospy.Subscriber("/sim/voxel_map", PointCloud2, on_voxel_map, queue_size=1, buff_size=2**24)
    rospy.Subscriber("/odom", Odometry, on_odom, queue_size=400, tcp_nodelay=True)
    rospy.Subscriber("/planner/goal", PoseStamped, on_goal, queue_size=5)
    rospy.Subscriber("/sim/status", EpisodeStatus, on_status, queue_size=20)
    rospy.Subscriber("/sim/frame_ack", FrameAck, on_ack, queue_size=200, tcp_nodelay=True)
    for name, topic in expert_topics.items():
        rospy.Subscriber(topic, Bspline, on_plan(name), queue_size=20, tcp_nodelay=True)
    if not cfg.expert_only:
        rospy.Subscriber(
            str(rospy.get_param("~learner_topic", "/learner/bspline")),
            Bspline,
            on_plan("learner"),
            queue_size=20,
            tcp_nodelay=True,
        )
    rospy.Subscriber("/camera/depth/image", Image, on_depth, queue_size=5, buff_size=2**24, tcp_nodelay=True)
    threading.Thread(target=watchdog, daemon=True).start()
    rospy.loginfo(
        f"imitation_collector: {cfg.algorithm.name} round {cfg.round_index}, sources {sources}, "
        f"{max_episodes} episodes -> {output_dir}"
    )
    rospy.spin()
