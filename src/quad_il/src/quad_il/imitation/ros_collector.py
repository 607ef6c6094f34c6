"""rospy adapter of the interactive collector (thin). The rospy wiring in `main()` is NOT YET TESTED: it waits
for the simulator, the expert in labeller mode and the policy node. Tested without ROS: the message
conversions and `CollectorCore` (pairing -> learner -> episode files),
tests/python/test_imitation_collector_core.py.

It is written against the topics of docs/CONVENTIONS.md. The decision logic it wraps (`learners`, `pairing`,
`dataset`) is ROS-free; this module only converts messages, runs the callbacks, forwards the chosen plan to
the tracker and writes episode files. rospy and the message packages are imported inside `main()`, so
importing this module needs no ROS.

Topics (private parameters in brackets):
  in   /odom (nav_msgs/Odometry), /camera/depth/image (sensor_msgs/Image 32FC1), /planner/goal
       (geometry_msgs/PoseStamped), /sim/status (quad_msgs/EpisodeStatus), /sim/voxel_map (PointCloud2,
       MEGA-DAgger), each expert's plan [~expert_topics: {name: topic}, default {expert: /planner/bspline}],
       the learner's plan [~learner_topic, default /learner/bspline]
  out  /tracker/track_bspline (action goal: the plan of whoever flies), ~executed (quad_msgs/Bspline),
       /sim/frame_ack (quad_msgs/FrameAck, consumer [~consumer_name], after each decision: in lockstep the
       simulator waits for it, so the decision is applied before time advances)
Parameters: ~round_config (the manager's round_XXX/algorithm.yaml), ~output_dir, ~episodes (stop after N),
  ~voxel_size_m (MEGA-DAgger's clearance map). Every plan must carry the stamp of the depth frame it was
  planned from as `start_time` (the lockstep pairing key, pairing.py).
"""

from __future__ import annotations

import json
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
from quad_il.imitation.safety import PointCloudClearance
from quad_il.imitation.types import Controller, EpisodeOutcome, ImitationError, Observation, Pair, Record


def load_round_config(path: str | Path) -> RoundAlgorithmConfig:
    with open(path) as fh:
        return RoundAlgorithmConfig.model_validate(yaml.safe_load(fh))


def spline_from_msg(msg: Any) -> SplineAction:
    ctrl = np.array([[p.x, p.y, p.z] for p in msg.pos_pts], dtype=np.float64).reshape(-1, 3)
    return SplineAction(
        ctrl,
        np.asarray(msg.knots, dtype=np.float64),
        int(msg.order),
        msg.start_time.to_sec(),
        int(msg.traj_id),
    )


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
        self.episodes_written = 0
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

    def finish_episode(self, episode_id: int, outcome: EpisodeOutcome) -> None:
        self.episode_records.extend(self.learner.end_episode(outcome))
        if self.episode_records:
            write_episode(self.output_dir, episode_id, self.episode_records)
            self.records_written += len(self.episode_records)
        self.episode_records = []
        self.episodes_written += 1


def main() -> None:  # pragma: no cover - needs a ROS master; exercised by the rostests of issue 9
    import actionlib
    import rospy
    from geometry_msgs.msg import PoseStamped
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
    expert_topics: dict[str, str] = dict(rospy.get_param("~expert_topics", {"expert": "/planner/bspline"}))
    if isinstance(cfg.algorithm, MegaDAggerConfig):
        missing = [e for e in cfg.algorithm.experts if e not in expert_topics]
        if missing:
            raise ImitationError(f"~expert_topics lacks the MEGA-DAgger experts {missing}")
    primary = next(iter(expert_topics))
    clearance = None
    if isinstance(cfg.algorithm, MegaDAggerConfig):
        cloud = rospy.wait_for_message("/sim/voxel_map", PointCloud2, timeout=30.0)
        pts = np.array(list(point_cloud2.read_points(cloud, field_names=("x", "y", "z"), skip_nans=True)))
        clearance = PointCloudClearance(pts.reshape(-1, 3), float(rospy.get_param("~voxel_size_m", 0.1)))
    learner = make_learner(cfg, np.random.default_rng(cfg.seed), clearance)
    sources = [*expert_topics, "learner"] if not cfg.expert_only else list(expert_topics)
    core = CollectorCore(learner, sources, primary, output_dir)

    tracker = actionlib.SimpleActionClient("/tracker/track_bspline", TrackBsplineAction)
    executed_pub = rospy.Publisher("~executed", Bspline, queue_size=10)
    ack_pub = rospy.Publisher("/sim/frame_ack", FrameAck, queue_size=10)
    state: dict[str, Any] = {"odom": [], "goal": None, "episode": None, "interrupted": False}
    # rospy runs each subscription's callbacks in its own thread: one lock serialises the core.
    lock = threading.Lock()

    def on_odom(msg: Any) -> None:
        state["odom"] = (state["odom"] + [msg])[-64:]

    def on_goal(msg: Any) -> None:
        state["goal"] = np.array([msg.pose.position.x, msg.pose.position.y, msg.pose.position.z])

    def act(frames: list[PairedFrame]) -> None:
        for frame, decision in core.frames(frames):
            if decision.controller is not Controller.NONE and decision.action is not None:
                msg = Bspline(
                    order=decision.action.order,
                    traj_id=decision.action.traj_id,
                    start_time=rospy.Time.from_sec(decision.action.start_time_s),
                    knots=decision.action.knots.tolist(),
                )
                msg.pos_pts = [_point(p) for p in decision.action.ctrl_pts_world]
                tracker.send_goal(TrackBsplineGoal(bspline=msg))
                executed_pub.publish(msg)
            ack_pub.publish(
                FrameAck(
                    consumer=consumer,
                    frame_seq=frame.obs.frame_seq,
                    stamp=rospy.Time.from_sec(frame.obs.stamp_s),
                )
            )

    def on_depth(msg: Any) -> None:
        if state["episode"] is None or state["goal"] is None or not state["odom"]:
            return
        t = msg.header.stamp.to_sec()
        odoms = [o for o in state["odom"] if o.header.stamp.to_sec() <= t] or state["odom"][:1]
        o = odoms[-1]
        pose, twist = o.pose.pose, o.twist.twist
        try:
            obs = Observation(
                stamp_s=t,
                frame_seq=msg.header.seq,
                episode_id=state["episode"],
                p_world_body=[pose.position.x, pose.position.y, pose.position.z],
                v_world=[twist.linear.x, twist.linear.y, twist.linear.z],
                q_world_body=[pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w],
                goal_world=state["goal"],
                depth_m=depth_from_msg(msg),
            )
        except ImitationError as e:
            rospy.logwarn_throttle(5.0, f"depth frame at {t:.3f} s rejected: {e}")
            return
        with lock:
            act(core.pairer.add_observation(obs))

    def on_plan(source: str) -> Any:
        def cb(msg: Any) -> None:
            try:
                action: SplineAction | None = spline_from_msg(msg)
            except ValueError as e:
                rospy.logwarn_throttle(5.0, f"{source} plan rejected: {e}")
                action = None
            with lock:
                act(core.pairer.add_action(source, msg.start_time.to_sec(), action))

        return cb

    def on_status(msg: Any) -> None:
        with lock:
            _on_status(msg)

    def _on_status(msg: Any) -> None:
        if state["episode"] is None and msg.active:
            state["episode"] = int(msg.episode_id)
            learner.start_episode(state["episode"])
        elif state["episode"] is not None and (not msg.active or int(msg.episode_id) != state["episode"]):
            outcome = EpisodeOutcome(
                reached_goal=msg.reached_goal,
                collided=msg.collided,
                collision_time_s=msg.collision_time.to_sec() if msg.collided else None,
                reason=msg.reason,
            )
            core.finish_episode(state["episode"], outcome)
            rospy.loginfo(f"episode {state['episode']} done ({msg.reason}); {core.records_written} records")
            state["episode"] = None
            if core.episodes_written >= max_episodes:
                rospy.signal_shutdown("episodes done")

    def finalise() -> None:
        # SIGINT (rospy's handler) and normal ends both land here: close the open episode, write the manifest.
        with lock:
            _finalise()

    def _finalise() -> None:
        if state["episode"] is not None:
            state["interrupted"] = True
            core.finish_episode(state["episode"], EpisodeOutcome(reason="collector interrupted"))
        write_json_atomic(
            output_dir / "collector_manifest.json",
            {
                "round_config": cfg.model_dump(mode="json"),
                "episodes": core.episodes_written,
                "records": core.records_written,
                "interrupted": state["interrupted"],
                "stats": vars(learner.stats),
                "pairer": vars(core.pairer.stats),
            },
        )

    rospy.on_shutdown(finalise)
    rospy.Subscriber("/odom", Odometry, on_odom, queue_size=50)
    rospy.Subscriber("/planner/goal", PoseStamped, on_goal, queue_size=1)
    rospy.Subscriber("/sim/status", EpisodeStatus, on_status, queue_size=10)
    rospy.Subscriber("/camera/depth/image", Image, on_depth, queue_size=5)
    for name, topic in expert_topics.items():
        rospy.Subscriber(topic, Bspline, on_plan(name), queue_size=10)
    if not cfg.expert_only:
        rospy.Subscriber(
            str(rospy.get_param("~learner_topic", "/learner/bspline")),
            Bspline,
            on_plan("learner"),
            queue_size=10,
        )
    rospy.spin()


def _point(p: np.ndarray) -> Any:  # pragma: no cover - ROS only
    from geometry_msgs.msg import Point

    return Point(float(p[0]), float(p[1]), float(p[2]))
