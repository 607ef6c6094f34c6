#!/usr/bin/env python3
"""Episode manager of a demonstration-collection run (`roslaunch quad_il collect.launch`).

For each episode: reset the simulator into the episode's seeded world with a start on the ground, take off
with the tracker's line tracker, send the goal to the expert, and wait (in sim time) for goal reached,
collision or timeout. Logs every episode's outcome and why to <output_dir>/episodes.csv, prints progress, and
stops after N episodes or M samples by shutting the launch down (`required="true"`), which lets the expert
finalise its dataset.
The episode logic (seeds, start/goal sampling, stop conditions) is quad_il.collection.episodes (ROS-free).
"""

from __future__ import annotations

import math
import sys
import threading
import time

import numpy as np
import rospy
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
from nav_msgs.msg import Odometry

from quad_il.collection.episodes import (
    EpisodeLog,
    EpisodeOutcome,
    StopCondition,
    load_collect_config,
    plan_episode,
)
from quad_msgs.msg import Bspline, EpisodeStatus
from quad_msgs.srv import Goto, ResetEpisode

GROUND_Z_M = 0.125  # the vehicle's collision box half height: the start rests on the ground


class EpisodeManager:
    def __init__(self) -> None:
        overrides = {
            "output_dir": rospy.get_param("~output_dir", None) or None,
            "episodes": rospy.get_param("~episodes", 0) or None,
            "max_samples": rospy.get_param("~max_samples", -1)
            if rospy.get_param("~max_samples", -1) >= 0
            else None,
        }
        seeds = str(rospy.get_param("~seeds", "")).strip()
        if seeds:
            overrides["seeds"] = [int(s) for s in seeds.replace(",", " ").split()]
        self.cfg = load_collect_config(rospy.get_param("~config"), overrides)
        self.takeoff_timeout_s = float(rospy.get_param("~takeoff_timeout_s", 15.0))
        self._lock = threading.Lock()
        self._status: EpisodeStatus | None = None
        self._odom: Odometry | None = None
        self._samples_episode = 0
        rospy.Subscriber("/sim/status", EpisodeStatus, self._on_status, queue_size=10)
        rospy.Subscriber("/odom", Odometry, self._on_odom, queue_size=1)
        rospy.Subscriber("/planner/bspline", Bspline, self._on_bspline, queue_size=100)
        self.goal_pub = rospy.Publisher("/planner/goal", PoseStamped, queue_size=1, latch=True)
        rospy.loginfo("episode_manager: waiting for /sim/reset and /tracker/goto")
        rospy.wait_for_service("/sim/reset")
        rospy.wait_for_service("/tracker/goto")
        self.reset_srv = rospy.ServiceProxy("/sim/reset", ResetEpisode)
        self.goto_srv = rospy.ServiceProxy("/tracker/goto", Goto)
        self.log = EpisodeLog(f"{self.cfg.output_dir}/episodes.csv")

    def _on_status(self, msg: EpisodeStatus) -> None:
        with self._lock:
            self._status = msg

    def _on_odom(self, msg: Odometry) -> None:
        with self._lock:
            self._odom = msg

    def _on_bspline(self, _msg: Bspline) -> None:
        with self._lock:
            self._samples_episode += 1

    def _wait(self, predicate, timeout_sim_s: float) -> bool:
        """Wait (sim time) until predicate() holds; False on timeout or shutdown."""
        t_end = rospy.Time.now() + rospy.Duration(timeout_sim_s)
        while not rospy.is_shutdown():
            if predicate():
                return True
            if rospy.Time.now() > t_end:
                return False
            time.sleep(0.002)
        return False

    def run_episode(self, index: int) -> EpisodeOutcome:
        spec = plan_episode(self.cfg, index)
        sx, sy, sz = spec.start_world
        start = Pose(
            position=Point(sx, sy, GROUND_Z_M),
            orientation=Quaternion(
                0.0, 0.0, math.sin(spec.start_yaw_rad / 2), math.cos(spec.start_yaw_rad / 2)
            ),
        )
        resp = self.reset_srv(seed=spec.seed, world_file="", start=start, goal=Point(*spec.goal_world))
        if not resp.success:
            return EpisodeOutcome(index, spec.seed, "reset_failed", resp.message, 0.0, 0)
        episode_id = resp.episode_id
        # Odometry of the new episode must reach the tracker before the goto starts from it.
        if not self._wait(lambda: self._status is not None and self._status.episode_id == episode_id, 10.0):
            return EpisodeOutcome(index, spec.seed, "reset_failed", "no status for the new episode", 0.0, 0)
        t0 = rospy.Time.now()
        takeoff = np.array([sx, sy, sz])
        self.goto_srv(position=Point(*takeoff), yaw=spec.start_yaw_rad, max_vel_mps=0.0, max_acc_mps2=0.0)

        def at_takeoff() -> bool:
            o = self._odom
            if o is None:
                return False
            p = o.pose.pose.position
            v = o.twist.twist.linear
            return math.dist((p.x, p.y, p.z), takeoff) < 0.15 and math.hypot(v.x, v.y, v.z) < 0.3

        if not self._wait(at_takeoff, self.takeoff_timeout_s):
            return EpisodeOutcome(index, spec.seed, "timeout", "take-off did not reach its altitude", 0.0, 0)
        with self._lock:
            self._samples_episode = 0
        goal = PoseStamped()
        goal.header.stamp = rospy.Time.now()
        goal.header.frame_id = "world"
        goal.pose.position = Point(*spec.goal_world)
        goal.pose.orientation.w = 1.0
        self.goal_pub.publish(goal)

        def ended() -> bool:
            s = self._status
            return (
                s is not None
                and s.episode_id == episode_id
                and (s.reached_goal or s.collided or not s.active)
            )

        finished = self._wait(ended, self.cfg.episode_timeout_s)
        duration = (rospy.Time.now() - t0).to_sec()
        with self._lock:
            samples = self._samples_episode
            status = self._status
        if rospy.is_shutdown():
            return EpisodeOutcome(
                index, spec.seed, "interrupted", "shutdown during the episode", duration, samples
            )
        if not finished:
            return EpisodeOutcome(
                index,
                spec.seed,
                "timeout",
                f"no goal within {self.cfg.episode_timeout_s} s",
                duration,
                samples,
            )
        outcome = "goal_reached" if status.reached_goal else ("collision" if status.collided else "ended")
        return EpisodeOutcome(index, spec.seed, outcome, status.reason, duration, samples)

    def run(self) -> None:
        stop = StopCondition(self.cfg)
        total_samples, finished = 0, 0
        counts: dict[str, int] = {}
        wall0 = time.monotonic()
        while not rospy.is_shutdown():
            done, why = stop.done(finished, total_samples)
            if done:
                rospy.loginfo(f"episode_manager: done: {why}")
                break
            out = self.run_episode(finished)
            self.log.append(out)
            finished += 1
            total_samples += out.samples
            counts[out.outcome] = counts.get(out.outcome, 0) + 1
            rospy.loginfo(
                f"episode {finished}/{self.cfg.episodes} seed {out.seed}: {out.outcome} ({out.reason}) "
                f"{out.sim_duration_s:.1f} s sim, {out.samples} samples; total {total_samples} samples, "
                f"{time.monotonic() - wall0:.0f} s wall; outcomes {counts}"
            )
        self.log.close()
        rospy.signal_shutdown("collection finished")


def main() -> int:
    rospy.init_node("episode_manager")
    try:
        EpisodeManager().run()
    except (ValueError, FileNotFoundError) as exc:
        rospy.logfatal(f"episode_manager: {exc}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
