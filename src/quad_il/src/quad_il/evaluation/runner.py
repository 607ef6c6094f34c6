"""The rospy episode runner of the closed-loop evaluation: flies a list of episodes with whatever controller
is running (the expert planner or a policy node) through the simulator's reset service, and records each
episode's outcome, time to goal, path length, clearance and decision latencies.

Per episode: reset the simulator into the episode's seeded world with the vehicle on the ground at the start,
take off with the tracker's line tracker to the start altitude, publish the goal on /planner/goal, and wait
(sim time) for goal reached, collision or the timeout. Every step is taken at a depth frame; in lockstep the
runner is one of the simulator's depth consumers and acts at held frames (quad_il.lockstep), so the same
episode's flight starts at the same sim time in every run. Decision latencies come from policy/decision
(policy nodes: preprocessing + forward + message) or planner/timing (expert: map update + plan).

Command line: quad_il.evaluation.runner_args (`--help`); needs ROS_MASTER_URI of a running simulator +
tracker + controller; results are appended as JSON lines.
"""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
import rospy
from geometry_msgs.msg import Point, Pose, Quaternion
from visualization_msgs.msg import MarkerArray

from quad_il.collection.episodes import EpisodeSpec
from quad_il.evaluation.episodes import (
    GROUND_Z_M,
    EpisodeResult,
    append_result,
    read_episodes,
)
from quad_il.evaluation.metrics import Box, boxes_from_markers, summarise_flight
from quad_il.evaluation.runner_args import parse_args
from quad_il.lockstep import ControllerGoal, FrameGate, Interrupted, OdometryHistory, TrackerGoto, wait_until
from quad_il.ros_params import wait_for_param
from quad_msgs.msg import EpisodeStatus, PlanTiming, PolicyDecision, SimStats
from quad_msgs.srv import ResetEpisode

# Where each controller answers a goal ("goal accepted: ..." / "goal rejected: ...").
STATUS_TOPIC = {"expert": "planner/status", "py": "policy/status", "cpp": "policy/status"}
WALL_WAIT_S = 30.0  # wall-time limit of any wait on another node


class EpisodeRunner:
    """Flies episodes frame by frame. With `consumer` (lockstep): the runner is one of the simulator's depth
    consumers and acts at held frames (quad_il.lockstep): the take-off's goto once the tracker has answered
    the frame's control period, the goal once the controller has decided the frame and then answered the
    goal. So every run of an episode starts its flight at the same sim time with the same state, and a
    deterministic controller flies it the same way. Without (`consumer` None) it acts at the newest frame."""

    def __init__(
        self,
        controller: str,
        episode_timeout_s: float = 60.0,
        takeoff_timeout_s: float = 20.0,
        vehicle_box_m: tuple[float, float, float] = (0.25, 0.25, 0.25),
        consumer: str | None = None,
        controller_consumer: str = "",
    ) -> None:
        """controller_consumer: the controller's FrameAck consumer name (lockstep; waited for before the
        goal is published at a frame, so that the goal takes effect from the next frame on)."""
        self.controller = controller
        self.episode_timeout_s = episode_timeout_s
        self.takeoff_timeout_s = takeoff_timeout_s
        self.vehicle_box_m = np.asarray(vehicle_box_m, dtype=np.float64)
        self.lockstep = consumer is not None
        self.controller_consumer = controller_consumer
        if self.lockstep and not controller_consumer:
            raise ValueError("a lockstep runner needs the controller's FrameAck consumer name")
        self._lock = threading.Lock()
        self._cv = threading.Condition(self._lock)
        self._status: EpisodeStatus | None = None
        self._boxes: list[Box] = []
        self._markers_seen = 0
        self._decisions: list[PolicyDecision] = []
        self._timings: list[PlanTiming] = []
        # Per episode id: the simulator's whole-run lockstep timeout count in its first and newest SimStats
        # (stamp, count) of that episode.
        self._stats_first: dict[int, int] = {}
        self._stats_last: dict[int, tuple[float, int]] = {}
        rospy.Subscriber("sim/status", EpisodeStatus, self._on_status, queue_size=10)
        rospy.Subscriber("sim/stats", SimStats, self._on_stats, queue_size=200, tcp_nodelay=True)
        rospy.Subscriber("sim/world_markers", MarkerArray, self._on_markers, queue_size=2)
        rospy.Subscriber("policy/decision", PolicyDecision, self._on_decision, queue_size=200)
        rospy.Subscriber("planner/timing", PlanTiming, self._on_timing, queue_size=200)
        self.goal = ControllerGoal(controller_consumer, STATUS_TOPIC[controller], self.lockstep, WALL_WAIT_S)
        # The whole episode's odometry: the take-off check and the recorded path.
        self.odom = OdometryHistory(keep=None, wall_wait_s=WALL_WAIT_S)
        self.goto = TrackerGoto(self.lockstep, wall_wait_s=WALL_WAIT_S)
        self.frames = FrameGate(consumer or "", self.lockstep, WALL_WAIT_S)
        rospy.wait_for_service("sim/reset", timeout=60.0)
        rospy.wait_for_service("tracker/goto", timeout=60.0)
        self.reset_srv = rospy.ServiceProxy("sim/reset", ResetEpisode)

    # ---- callbacks ----
    def _on_status(self, msg: EpisodeStatus) -> None:
        with self._cv:
            self._status = msg
            self._cv.notify_all()

    def _on_stats(self, msg: SimStats) -> None:
        n = int(msg.lockstep_command_timeouts + msg.lockstep_ack_timeouts)
        with self._cv:
            self._stats_first.setdefault(msg.episode_id, n)
            self._stats_last[msg.episode_id] = (msg.header.stamp.to_sec(), n)
            self._cv.notify_all()

    def _on_markers(self, msg: MarkerArray) -> None:
        boxes = boxes_from_markers(msg.markers)
        with self._cv:
            self._boxes = boxes
            self._markers_seen += 1
            self._cv.notify_all()

    def _on_decision(self, msg: PolicyDecision) -> None:
        with self._cv:
            self._decisions.append(msg)
            self._cv.notify_all()

    def _on_timing(self, msg: PlanTiming) -> None:
        with self._lock:
            self._timings.append(msg)

    # ---- helpers ----
    def _wait(self, predicate: Callable[[], bool], what: str, timeout_wall_s: float = WALL_WAIT_S) -> None:
        wait_until(self._cv, predicate, what, timeout_wall_s)

    def _result(
        self, spec: EpisodeSpec, outcome: str, reason: str, lockstep_timeouts: int | None
    ) -> EpisodeResult:
        return EpisodeResult(
            self.controller, spec.index, spec.seed, outcome, reason, lockstep_timeouts=lockstep_timeouts
        )

    def _lockstep_timeouts(self, episode_id: int, t: float, baseline: int) -> int:
        """The simulator's lockstep timeouts from the episode's start (whole-run count `baseline` then) up to
        sim time t. In lockstep the simulator publishes its SimStats before every depth frame, so the one
        stamped at the frame held now is on its way; a free-running one publishes them every wall second."""
        eps = 1e-6
        self._wait(
            lambda: episode_id in self._stats_last and self._stats_last[episode_id][0] >= t - eps,
            f"simulator statistics (sim/stats) of episode {episode_id} at t={t:.3f}",
        )
        with self._lock:
            return self._stats_last[episode_id][1] - baseline

    # ---- one episode ----
    def run(self, spec: EpisodeSpec, reset: bool = True) -> EpisodeResult:
        """Flies one episode. reset=False: the simulator already runs this episode (its config holds the
        episode's world seed, start and goal), e.g. right after its launch. Raises TimeoutError when a node
        does not answer within WALL_WAIT_S (wall time): a broken setup, not an outcome of the controller."""
        sx, sy, sz = spec.start_world
        yaw = spec.start_yaw_rad
        with self._lock:
            self._decisions, self._timings = [], []
        self.odom.clear()
        if reset:
            goal = Point(*spec.goal_world)
            start = Pose(
                position=Point(sx, sy, GROUND_Z_M),
                orientation=Quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
            )
            with self._lock:
                markers_before = self._markers_seen
            # Keyed by the episode's index (issue 32): its stamps, id and flight do not depend on earlier ones
            resp = self.reset_srv(
                seed=spec.seed, world_file="", start=start, goal=goal, keyed=True, episode_index=spec.index
            )
            self.frames.held = None  # the reset released the held frame
            if not resp.success:
                return self._result(spec, "reset_failed", resp.message, None)
            episode_id = resp.episode_id
            self._wait(
                lambda: self._status is not None and self._status.episode_id == episode_id,
                f"status of episode {episode_id}",
            )
            # The simulator publishes its statistics at the reset: its timeouts before this episode.
            self._wait(lambda: episode_id in self._stats_first, f"statistics of episode {episode_id}")
            with self._lock:
                baseline = self._stats_first[episode_id]
            # The simulator republishes its (latched) world markers at a reset: wait for this world's boxes.
            self._wait(lambda: self._markers_seen > markers_before, "world markers of the new episode")
        else:
            self._wait(
                lambda: self._status is not None and self._markers_seen > 0,
                "simulator status and world markers",
            )
            baseline = 0  # the simulator has run this episode since its start: its counts are the episode's
        with self._lock:
            episode_id = self._status.episode_id
            t_episode = self._status.header.stamp.to_sec()
        # Take-off at the first frame of the episode that the tracker takes the goto at.
        t, _ = self.frames.next_frame(t_episode)
        why = ""
        for _ in range(20):
            why = self.goto((sx, sy, sz), yaw, at_s=t)
            self.frames.ack()
            if not why:
                break
            t, _ = self.frames.next_frame(t)
        else:
            return self._result(
                spec,
                "takeoff_failed",
                f"goto refused: {why}",
                self._lockstep_timeouts(episode_id, t, baseline),
            )
        t_takeoff = t
        while True:
            t, _ = self.frames.next_frame(t)
            p, speed = self.odom.at(t)
            if math.dist(p, (sx, sy, sz)) < 0.15 and speed < 0.3:
                break
            if t - t_takeoff > self.takeoff_timeout_s:
                return self._result(
                    spec,
                    "takeoff_failed",
                    f"take-off to {[round(v, 2) for v in (sx, sy, sz)]} did not settle",
                    self._lockstep_timeouts(episode_id, t, baseline),
                )
            self.frames.ack()
        # The goal at this frame once the controller has decided it; the frame is released once the controller
        # has answered the goal (lockstep).
        answer = self.goal.give(spec.goal_world, t)
        t0 = t
        self.frames.ack()
        if answer.startswith("goal rejected"):
            return self._result(
                spec,
                "reset_failed",
                f"the controller refused the episode's goal: {answer}",
                self._lockstep_timeouts(episode_id, t, baseline),
            )
        # Fly, one frame at a time, until the simulator reports the end or the sim-time limit.
        outcome, reason = "timeout", f"no goal within {self.episode_timeout_s:g} s"
        frames = [t0]
        while True:
            t, _ = self.frames.next_frame(t)
            with self._lock:
                s = self._status
            if (
                s is not None
                and s.episode_id == episode_id
                and (s.reached_goal or s.collided or not s.active)
            ):
                t_end = s.sim_time.to_sec()
                if s.reached_goal:
                    outcome, reason = "goal_reached", s.reason
                elif s.collided:
                    outcome, reason = "collision", s.reason
                else:
                    reason = f"episode ended: {s.reason}"
                break
            frames.append(t)
            if t - t0 > self.episode_timeout_s:
                t_end = t
                break
            self.frames.ack()
        # The frame at which the episode ended stays held (lockstep): nothing happens after it. The policy's
        # decision of the last frame up to the end is on its way (on another topic than its acknowledgement).
        if self.controller != "expert":
            last = max(f for f in frames if f <= t_end + 1e-6)
            try:
                self._wait(
                    lambda: any(d.header.stamp.to_sec() >= last - 1e-6 for d in self._decisions),
                    f"policy decision of frame {last:.3f}",
                    5.0,
                )
            except TimeoutError:
                rospy.logwarn(f"[eval] no policy decision of frame {last:.3f}: counted from those that came")
        return self._finish(
            spec, outcome, reason, t0, t_end, self._lockstep_timeouts(episode_id, t, baseline)
        )

    def _finish(
        self, spec: EpisodeSpec, outcome: str, reason: str, t0: float, t_end: float, lockstep_timeouts: int
    ) -> EpisodeResult:
        """The episode's result from what was recorded between the goal (t0) and the end (t_end), sim time."""
        eps = 1e-6
        self.odom.at(t_end)  # the path up to the end has arrived (odometry travels on its own topic)
        points = np.asarray(self.odom.positions(t0, t_end), dtype=np.float64).reshape(-1, 4)
        with self._lock:
            decisions = [d for d in self._decisions if t0 - eps <= d.header.stamp.to_sec() <= t_end + eps]
            timings = [m for m in self._timings if t0 - eps <= m.header.stamp.to_sec() <= t_end + eps]
            boxes = list(self._boxes)
        decided = [round(d.decision_ms, 4) for d in decisions if d.status == "decided"]
        last = decisions[-1] if decisions else None
        return summarise_flight(
            self._result(spec, outcome, reason, lockstep_timeouts),
            t0,
            t_end,
            points,
            boxes,
            self.vehicle_box_m,
            decision_ms=decided,
            plan_ms=[m.map_update_ms + m.total_ms for m in timings],
            counts=dict(zip(last.count_names, map(int, last.count_values), strict=True)) if last else None,
            tracker_rejections=last.tracker_rejections if last else 0,
        )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(rospy.myargv(argv if argv is not None else sys.argv)[1:])
    # rospy reads /use_sim_time once, in init_node: wait until the launch file has set it (the runner may
    # start before roslaunch has set its parameters), or every wait below would run on the wall clock.
    if not wait_for_param("/use_sim_time", 60.0):
        print("[eval] /use_sim_time is not set: is the simulator's launch running?", file=sys.stderr)
        return 1
    rospy.init_node(f"eval_runner_{args.controller}", disable_signals=False)
    box = tuple(float(x) for x in args.vehicle_box_m.split(","))
    runner = EpisodeRunner(
        args.controller,
        args.episode_timeout_s,
        args.takeoff_timeout_s,
        box,
        consumer=args.lockstep_consumer or None,
        controller_consumer=args.controller_consumer,
    )
    specs = read_episodes(args.episodes)
    if args.no_reset and len(specs) != 1:
        print("[eval] --no-reset flies exactly one episode", file=sys.stderr)
        return 1
    for spec in specs:
        if rospy.is_shutdown():
            return 1
        wall0 = time.monotonic()
        try:
            res = runner.run(spec, reset=not args.no_reset)
        except (TimeoutError, Interrupted) as exc:
            print(f"[eval {args.controller}] episode {spec.index} seed {spec.seed}: {exc}", file=sys.stderr)
            return 1
        append_result(args.out, res)
        print(
            f"[eval {args.controller}] episode {spec.index} seed {spec.seed}: {res.outcome} ({res.reason}); "
            f"{res.flight_time_s:.1f} s sim, {time.monotonic() - wall0:.1f} s wall, "
            f"{res.decisions} decisions, {res.lockstep_timeouts} lockstep timeouts",
            file=sys.stderr,
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
