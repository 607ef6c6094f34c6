#!/usr/bin/env python3
"""Episode manager of a demonstration-collection run (`roslaunch quad_il collect.launch`, docs/collect.md).

For each episode: restart the tracker (kr_tracker keeps its previous reference across a simulator reset),
reset the simulator into the episode's seeded world with a start on the ground, take off with the tracker's
line tracker, send the goal to the expert, and end the episode on goal reached, collision or timeout (sim
time). Logs every episode's outcome and why to <output_dir>/episodes.csv, prints progress, and stops after N
episodes or M samples by shutting the launch down (`required="true"`), which lets the expert finalise its
dataset.

Every decision is taken at a depth frame (its camera_info, same stamp) from data stamped at or before it. In
lockstep the manager is one of the simulator's depth consumers: it acknowledges a frame only once its decision
for that frame has taken effect (the goto answered, the planner has taken the goal), and it holds the frame at
which an episode ends while it restarts the tracker and resets. The same seeds therefore give the same flights
and the same records, whatever the machine's load. The episode logic (seeds, start/goal sampling, stop
conditions) is quad_il.collection.episodes (ROS-free).
"""

from __future__ import annotations

import bisect
import math
import sys
import threading
import time
import xmlrpc.client

import rosnode
import rospy
import yaml
from geometry_msgs.msg import Point, Pose, Quaternion
from rosgraph_msgs.msg import Clock

from quad_il.collection.episodes import (
    EpisodeLog,
    EpisodeOutcome,
    StopCondition,
    manager_config,
    plan_episode,
)
from quad_il.lockstep import ControllerGoal, FrameGate, Interrupted, OdometryHistory, TrackerGoto, wait_until
from quad_il.ros_params import MissingParameterError, require_param
from quad_msgs.msg import EpisodeStatus, PlanTiming
from quad_msgs.srv import ResetEpisode

GROUND_Z_M = 0.125  # the vehicle's collision box half height: the start rests on the ground
TAKEOFF_TOLERANCE_M = 0.15
TAKEOFF_MAX_SPEED_MPS = 0.3
WALL_WAIT_S = 30.0  # wall-time limit of any wait on another node
LAUNCH_FILES = "launch/collect.launch or launch/il_sim.launch"  # where this node's parameters are set


class EpisodeManager:
    def __init__(self) -> None:
        params = {
            k: rospy.get_param(f"~{k}")
            for k in ("output_dir", "seeds", "episodes", "max_samples", "episode_timeout_s")
            if rospy.has_param(f"~{k}")
        }
        self.cfg = manager_config(require_param("~config", LAUNCH_FILES), params)
        self.lockstep = bool(require_param("~lockstep", LAUNCH_FILES))
        self.consumer = str(require_param("~frame_ack_consumer", LAUNCH_FILES))
        self.planner_consumer = str(require_param("~planner_consumer", LAUNCH_FILES))
        # A node name relative to this node's namespace (the tracker beside it), resolved for the master.
        self.tracker_node = rospy.resolve_name(str(require_param("~tracker_node", LAUNCH_FILES)))
        odom_period_s = float(require_param("~odom_period_s", LAUNCH_FILES))
        # Topic names as the tracker's bus info reports them (resolved in this node's namespace).
        self._odom_topic = rospy.resolve_name("odom")
        self._cmd_topic = rospy.resolve_name("so3_cmd")
        self._lock = threading.Lock()
        self._cv = threading.Condition(self._lock)
        self._status: EpisodeStatus | None = None
        self._successes: list[float] = []  # stamps of successful plans (= records)
        self.odom = OdometryHistory(odom_period_s, wall_wait_s=WALL_WAIT_S)
        self.goto = TrackerGoto(self.lockstep, odom_period_s, WALL_WAIT_S)
        rospy.Subscriber("sim/status", EpisodeStatus, self._on_status, queue_size=10)
        rospy.Subscriber("planner/timing", PlanTiming, self._on_timing, queue_size=100)
        # The planner acknowledges frames and answers goals in either time mode: always waited for.
        self.goal = ControllerGoal(self.planner_consumer, "planner/status", True, WALL_WAIT_S)
        self.clock_pub = rospy.Publisher("/clock", Clock, queue_size=1) if self.lockstep else None
        self.frames = FrameGate(self.consumer, self.lockstep, WALL_WAIT_S)
        rospy.loginfo("episode_manager: waiting for sim/reset and tracker/goto")
        rospy.wait_for_service("sim/reset")
        rospy.wait_for_service("tracker/goto")
        self.reset_srv = rospy.ServiceProxy("sim/reset", ResetEpisode)
        self.log = EpisodeLog(f"{self.cfg.output_dir}/episodes.csv")
        self.resumed_at = 0  # finished episodes found in episodes.csv at start (a resumed run)
        # Sim time flown in episodes (keyed episodes start 1000 s apart: the gaps between them are not flown).
        self.episode_start_s: float | None = None
        self.sim_s = 0.0

    # ---- subscriber threads ----
    def _on_status(self, msg: EpisodeStatus) -> None:
        with self._cv:
            self._status = msg
            self._cv.notify_all()

    def _on_timing(self, msg: PlanTiming) -> None:
        if msg.status.startswith("success"):
            with self._cv:
                self._successes.append(msg.header.stamp.to_sec())

    # ---- helpers (main thread) ----
    def _wait(self, predicate, what: str, timeout_wall_s: float = WALL_WAIT_S) -> None:
        wait_until(self._cv, predicate, what, timeout_wall_s)

    def _kill_tracker(self) -> str:
        """Ask the tracker to shut down (roslaunch respawns it); returns the old node's URI."""
        try:
            code, _, old_uri = rospy.get_master().lookupNode(self.tracker_node)
        except Exception:  # noqa: BLE001 - the master may refuse
            code, old_uri = 0, ""
        rosnode.kill_nodes([self.tracker_node])
        return old_uri if code == 1 else ""

    def _wait_tracker(self, old_uri: str) -> None:
        """Wait for the respawned tracker to be connected: odometry in, commands out, goto served."""
        master = rospy.get_master()
        deadline = time.monotonic() + WALL_WAIT_S
        while True:
            if rospy.is_shutdown():
                raise Interrupted("restarting the tracker")
            if time.monotonic() > deadline:
                raise TimeoutError(
                    f"{self.tracker_node} did not come back within {WALL_WAIT_S:.0f} s (respawn)"
                )
            time.sleep(0.05)
            try:
                code, _, uri = master.lookupNode(self.tracker_node)
            except Exception:  # noqa: BLE001
                continue
            if code != 1 or not uri or uri == old_uri:
                continue
            try:
                _, _, bus = xmlrpc.client.ServerProxy(uri).getBusInfo(rospy.get_name())
            except (OSError, xmlrpc.client.Error):
                continue
            # roscpp: [id, peer, direction, transport, topic, connected, ...]
            odom_in = any(c[2] == "i" and c[4] == self._odom_topic and c[5] for c in bus)
            cmd_out = any(c[2] == "o" and c[4] == self._cmd_topic for c in bus)
            # /clock from the simulator and from this node (inbound connections are to publisher URIs).
            clock_in = sum(1 for c in bus if c[2] == "i" and c[4] == "/clock") >= 2
            if odom_in and (cmd_out or not self.lockstep) and (clock_in or not self.lockstep):
                break
        rospy.wait_for_service("tracker/goto", timeout=WALL_WAIT_S)
        if self.lockstep and self.frames.held is not None:
            # The held simulator publishes no /clock: give the new tracker the current sim time (the held
            # frame's stamp, the last /clock the simulator published, so a repeat for every other node) before
            # its first odometry. kr_tracker stamps odometry receipt with its clock; at 0 its watchdog would
            # declare the odometry stale and publish a safe command competing with the real one.
            self.clock_pub.publish(Clock(clock=self.frames.held))
            time.sleep(0.05)

    def _records_since(self, t0: float) -> int:
        with self._lock:
            return len(self._successes) - bisect.bisect_left(self._successes, t0)

    # ---- one episode ----
    def run_episode(self, index: int, samples_before: int) -> EpisodeOutcome:
        spec = plan_episode(self.cfg, index)
        self.episode_start_s = None

        def outcome(kind: str, reason: str, t_start: float, t_now: float, records: int) -> EpisodeOutcome:
            return EpisodeOutcome(index, spec.seed, kind, reason, max(0.0, t_now - t_start), records)

        # Hold the simulator (lockstep) at a frame of the previous episode while the tracker restarts.
        if self.frames.held is None:
            # The first hold: a fixed time into the simulator's initial episode (FrameGate's start-up
            # acknowledgement), whether or not that was needed, so every run's episodes have the same stamps
            # (floating-point time arithmetic then gives bit-identical flights).
            self.frames.next_frame(0.0)
        if self.cfg.restart_tracker and self.lockstep:
            self._wait_tracker(self._kill_tracker())
        sx, sy, sz = spec.start_world
        start = Pose(
            position=Point(sx, sy, GROUND_Z_M),
            orientation=Quaternion(
                0.0, 0.0, math.sin(spec.start_yaw_rad / 2), math.cos(spec.start_yaw_rad / 2)
            ),
        )
        old_tracker = ""
        if self.cfg.restart_tracker and not self.lockstep:
            # Not holding the simulator: the new tracker must only see the new episode's odometry.
            old_tracker = self._kill_tracker()
        # Keyed by the episode's index in the run (issue 32): its stamps and id, so its flight and records,
        # are the same whether the run flew the episodes before it in this launch or was resumed.
        resp = self.reset_srv(
            seed=spec.seed,
            world_file="",
            start=start,
            goal=Point(*spec.goal_world),
            keyed=True,
            episode_index=index,
        )
        self.frames.held = None  # the reset released the held frame
        if not resp.success:
            return outcome("reset_failed", resp.message, 0.0, 0.0, 0)
        episode_id = resp.episode_id
        self._wait(
            lambda: self._status is not None and self._status.episode_id == episode_id,
            f"status of episode {episode_id}",
        )
        t0 = self._status.header.stamp.to_sec()
        self.episode_start_s = t0
        if self.cfg.restart_tracker and not self.lockstep:
            self._wait_tracker(old_tracker)
        # Take-off at the first frame of the episode.
        t, _ = self.frames.next_frame(t0)
        why = self.goto(spec.start_world, spec.start_yaw_rad, at_s=t)
        self.frames.ack()
        if why:
            return outcome("reset_failed", f"take-off refused: {why}", t0, t, 0)
        while True:
            t, _ = self.frames.next_frame(t)
            p, speed = self.odom.at(t)
            if math.dist(p, spec.start_world) < TAKEOFF_TOLERANCE_M and speed < TAKEOFF_MAX_SPEED_MPS:
                break
            if t - t0 > self.cfg.takeoff_timeout_s:
                return outcome("timeout", "take-off did not reach its altitude", t0, t, 0)
            self.frames.ack()
        # The goal, at this frame once the planner has processed it; the frame is acknowledged once the
        # planner has taken (or rejected) the goal.
        answer = self.goal.give(spec.goal_world, t)
        t_goal = t
        self.frames.ack()
        if answer.startswith("goal rejected"):
            return outcome("goal_rejected", answer, t_goal, t, 0)
        stop = StopCondition(self.cfg)
        while True:
            t, _ = self.frames.next_frame(t)
            records = self._records_since(t_goal)
            with self._lock:
                s = self._status
            if s is not None and s.episode_id == episode_id:
                if s.reached_goal:
                    return outcome("goal_reached", s.reason, t_goal, t, records)
                if s.collided:
                    return outcome("collision", s.reason, t_goal, t, records)
                if not s.active:
                    return outcome("ended", s.reason, t_goal, t, records)
            if t - t_goal > self.cfg.episode_timeout_s:
                return outcome(
                    "timeout", f"no goal within {self.cfg.episode_timeout_s:g} s", t_goal, t, records
                )
            done, why = stop.done(0, samples_before + records)
            if done:
                return outcome("stopped", why, t_goal, t, records)
            self.frames.ack()

    def run(self) -> int:
        stop = StopCondition(self.cfg)
        # A resumed run (collect.launch resume:=true) continues after the finished episodes of episodes.csv,
        # which quad_il.collection.resume has checked against the dataset before any node started.
        previous = EpisodeLog.read(self.log.path)
        total, finished = sum(o.samples for o in previous), len(previous)
        counts: dict[str, int] = {}
        for o in previous:
            counts[o.outcome] = counts.get(o.outcome, 0) + 1
        if previous:
            rospy.loginfo(
                f"episode_manager: resuming after {finished} finished episodes ({total} samples) of "
                f"{self.log.path}"
            )
        self.resumed_at = finished
        wall0 = time.monotonic()
        rospy.loginfo(
            f"episode_manager: {self.cfg.episodes} episodes, seeds "
            f"{self.cfg.seeds or f'{self.cfg.first_seed}...'}, max samples {self.cfg.max_samples or 'none'}, "
            f"{'lockstep' if self.lockstep else 'free-running'} simulator, output {self.cfg.output_dir}"
        )
        code = 0
        try:
            while not rospy.is_shutdown():
                done, why = stop.done(finished, total)
                if done:
                    rospy.loginfo(f"episode_manager: done: {why}")
                    break
                try:
                    out = self.run_episode(finished, total)
                except Interrupted as exc:
                    rospy.logwarn(f"episode_manager: interrupted while {exc}")
                    break
                except (TimeoutError, rospy.ServiceException, rospy.ROSException) as exc:
                    rospy.logerr(f"episode_manager: episode {finished}: {exc}; stopping the run")
                    code = 1
                    break
                if self.episode_start_s is not None:
                    self.sim_s += max(0.0, self.frames.last_frame_s - self.episode_start_s)
                self.log.append(out)
                finished += 1
                total += out.samples
                counts[out.outcome] = counts.get(out.outcome, 0) + 1
                print(
                    f"[collect] episode {finished}/{self.cfg.episodes} seed {out.seed}: {out.outcome} "
                    f"({out.reason}) {out.sim_duration_s:.1f} s sim, {out.samples} samples; total {total} "
                    f"samples, {time.monotonic() - wall0:.0f} s wall; outcomes {counts}",
                    flush=True,
                )
                if out.outcome == "stopped":
                    break
        finally:
            self.log.close()
            self._write_summary(finished, total, counts, time.monotonic() - wall0)
        rospy.signal_shutdown("collection finished")
        return code

    def _write_summary(self, finished: int, samples: int, counts: dict[str, int], wall_s: float) -> None:
        """<output_dir>/collect_summary.yaml: what the run did and how fast (sim seconds per wall second)."""
        sim_s = self.sim_s
        stop_done, _ = StopCondition(self.cfg).done(finished, samples)
        summary = {
            # the run reached its stop condition (false after an interruption: resume:=true continues it)
            "complete": bool(stop_done or counts.get("stopped", 0)),
            "episodes_planned": self.cfg.episodes,
            "resumed_at_episode": self.resumed_at,
            "episodes": finished,
            "samples": samples,
            "outcomes": counts,
            "lockstep": self.lockstep,
            "sim_s": round(sim_s, 6),
            "wall_s": round(wall_s, 3),
            "real_time_factor": round(sim_s / wall_s, 4) if wall_s > 0 else 0.0,
        }
        path = f"{self.cfg.output_dir}/collect_summary.yaml"
        with open(path, "w") as f:
            yaml.safe_dump(summary, f, sort_keys=False)
        print(
            f"[collect] finished: {finished} episodes, {samples} samples, {sim_s:.1f} s sim in "
            f"{wall_s:.1f} s wall (real-time factor {summary['real_time_factor']:.2f}); outcomes {counts}; "
            f"summary {path}",
            flush=True,
        )


def main() -> int:
    rospy.init_node("episode_manager")
    try:
        manager = EpisodeManager()
    except (ValueError, FileNotFoundError, MissingParameterError) as exc:
        rospy.logfatal(f"episode_manager: {exc}")
        print(f"episode_manager: error: {exc}", file=sys.stderr, flush=True)
        return 2
    return manager.run()


if __name__ == "__main__":
    sys.exit(main())
