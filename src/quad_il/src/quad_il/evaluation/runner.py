"""The rospy episode runner of the closed-loop evaluation: flies a list of episodes with whatever controller
is running (the expert planner or a policy node) through the simulator's reset service, and records each
episode's outcome, time to goal, path length, clearance and decision latencies.

Per episode: reset the simulator into the episode's seeded world with the vehicle on the ground at the start,
take off with the tracker's line tracker to the start altitude, publish the goal on /planner/goal, and wait
(sim time) for goal reached, collision or the timeout. Decision latencies come from policy/decision (policy
nodes: preprocessing + forward + message) or planner/timing (expert: map update + plan).

    python -m quad_il.evaluation.runner --episodes episodes.json --controller cpp --out cpp.jsonl
        [--episode-timeout-s 60] [--takeoff-timeout-s 20] [--vehicle-box-m 0.25,0.25,0.25]
(needs ROS_MASTER_URI of a running simulator + tracker + controller; results are appended as JSON lines)
"""

from __future__ import annotations

import argparse
import math
import sys
import threading
import time
from collections.abc import Callable

import numpy as np
import rospy
from geometry_msgs.msg import Point, Pose, PoseStamped, Quaternion
from nav_msgs.msg import Odometry
from visualization_msgs.msg import MarkerArray

from quad_il.collection.episodes import EpisodeSpec
from quad_il.evaluation.episodes import GROUND_Z_M, EpisodeResult, append_result, read_episodes
from quad_il.evaluation.metrics import Box, clearance_lower_bound, path_length
from quad_msgs.msg import EpisodeStatus, PlanTiming, PolicyDecision
from quad_msgs.srv import Goto, ResetEpisode


class EpisodeRunner:
    def __init__(
        self,
        controller: str,
        episode_timeout_s: float = 60.0,
        takeoff_timeout_s: float = 20.0,
        vehicle_box_m: tuple[float, float, float] = (0.25, 0.25, 0.25),
    ) -> None:
        self.controller = controller
        self.episode_timeout_s = episode_timeout_s
        self.takeoff_timeout_s = takeoff_timeout_s
        self.vehicle_box_m = np.asarray(vehicle_box_m, dtype=np.float64)
        self._lock = threading.Lock()
        self._status: EpisodeStatus | None = None
        self._odom: Odometry | None = None
        self._odom_count = 0
        self._boxes: list[Box] = []
        self._markers_seen = 0
        self._recording = False
        self._points: list[tuple[float, float, float, float]] = []
        self._decisions: list[PolicyDecision] = []
        self._timings: list[PlanTiming] = []
        rospy.Subscriber("/sim/status", EpisodeStatus, self._on_status, queue_size=10)
        rospy.Subscriber("/odom", Odometry, self._on_odom, queue_size=50, tcp_nodelay=True)
        rospy.Subscriber("/sim/world_markers", MarkerArray, self._on_markers, queue_size=2)
        rospy.Subscriber("/policy/decision", PolicyDecision, self._on_decision, queue_size=200)
        rospy.Subscriber("/planner/timing", PlanTiming, self._on_timing, queue_size=200)
        self.goal_pub = rospy.Publisher("/planner/goal", PoseStamped, queue_size=1, latch=True)
        rospy.wait_for_service("/sim/reset", timeout=60.0)
        rospy.wait_for_service("/tracker/goto", timeout=60.0)
        self.reset_srv = rospy.ServiceProxy("/sim/reset", ResetEpisode)
        self.goto_srv = rospy.ServiceProxy("/tracker/goto", Goto)

    # ---- callbacks ----
    def _on_status(self, msg: EpisodeStatus) -> None:
        with self._lock:
            self._status = msg

    def _on_odom(self, msg: Odometry) -> None:
        with self._lock:
            self._odom = msg
            self._odom_count += 1
            if self._recording:
                p = msg.pose.pose.position
                self._points.append((msg.header.stamp.to_sec(), p.x, p.y, p.z))

    def _on_markers(self, msg: MarkerArray) -> None:
        boxes = [
            Box(
                np.array([m.pose.position.x, m.pose.position.y, m.pose.position.z]),
                np.array(
                    [m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w]
                ),
                np.array([m.scale.x, m.scale.y, m.scale.z]),
            )
            for m in msg.markers
            if m.ns == "boxes" and m.action == m.ADD
        ]
        with self._lock:
            self._boxes = boxes
            self._markers_seen += 1

    def _on_decision(self, msg: PolicyDecision) -> None:
        with self._lock:
            if self._recording:
                self._decisions.append(msg)

    def _on_timing(self, msg: PlanTiming) -> None:
        with self._lock:
            if self._recording:
                self._timings.append(msg)

    # ---- helpers ----
    def _wait(self, predicate: Callable[[], bool], timeout_sim_s: float, wall_cap_s: float = 600.0) -> bool:
        """Wait until predicate() holds: False after timeout_sim_s of sim time (which stands still while the
        simulator waits for its lockstep peers), after wall_cap_s of wall time, or on shutdown."""
        t_end = rospy.Time.now() + rospy.Duration(timeout_sim_s)
        wall_end = time.monotonic() + wall_cap_s
        while not rospy.is_shutdown() and time.monotonic() < wall_end:
            with self._lock:
                if predicate():
                    return True
            if rospy.Time.now() > t_end:
                return False
            time.sleep(0.002)
        return False

    def _result(self, spec: EpisodeSpec, outcome: str, reason: str) -> EpisodeResult:
        return EpisodeResult(self.controller, spec.index, spec.seed, outcome, reason)

    # ---- one episode ----
    def run(self, spec: EpisodeSpec, reset: bool = True) -> EpisodeResult:
        """Flies one episode. reset=False: the simulator already runs this episode (its config holds the
        episode's world seed, start and goal), e.g. right after its launch."""
        sx, sy, sz = spec.start_world
        yaw = spec.start_yaw_rad
        if reset:
            start = Pose(
                position=Point(sx, sy, GROUND_Z_M),
                orientation=Quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)),
            )
            with self._lock:
                markers_before = self._markers_seen
            resp = self.reset_srv(seed=spec.seed, world_file="", start=start, goal=Point(*spec.goal_world))
            if not resp.success:
                return self._result(spec, "reset_failed", resp.message)
            episode_id = resp.episode_id
            if not self._wait(
                lambda: self._status is not None and self._status.episode_id == episode_id, 10.0
            ):
                return self._result(spec, "reset_failed", "no status for the new episode")
            # The simulator republishes its (latched) world markers at a reset: wait for this world's boxes.
            self._wait(lambda: self._markers_seen > markers_before, 5.0)
        else:
            if not self._wait(lambda: self._status is not None and self._markers_seen > 0, 60.0):
                return self._result(spec, "reset_failed", "no status or world markers from the simulator")
            episode_id = self._status.episode_id
        # The new episode's odometry must reach the tracker before the goto starts from it (in lockstep the
        # simulator first waits for its command source and depth consumers to connect).
        with self._lock:
            odom_before = self._odom_count
        if not self._wait(lambda: self._odom_count > odom_before + 2, 10.0):
            return self._result(spec, "takeoff_failed", "no odometry after the reset")
        takeoff = np.array([sx, sy, sz])
        why = ""
        for _ in range(20):
            resp = self.goto_srv(position=Point(sx, sy, sz), yaw=yaw, max_vel_mps=0.0, max_acc_mps2=0.0)
            if resp.success:
                break
            why = resp.message
            rospy.sleep(0.1)
        else:
            return self._result(spec, "takeoff_failed", f"goto refused: {why}")

        def at_takeoff() -> bool:
            o = self._odom
            if o is None:
                return False
            p, v = o.pose.pose.position, o.twist.twist.linear
            return bool(
                np.linalg.norm([p.x - sx, p.y - sy, p.z - sz]) < 0.15 and math.hypot(v.x, v.y, v.z) < 0.3
            )

        if not self._wait(at_takeoff, self.takeoff_timeout_s):
            return self._result(
                spec, "takeoff_failed", f"take-off to {takeoff.round(2).tolist()} did not settle"
            )
        with self._lock:
            self._points, self._decisions, self._timings = [], [], []
            self._recording = True
        goal = PoseStamped()
        goal.header.stamp = rospy.Time.now()
        goal.header.frame_id = "world"
        goal.pose.position = Point(*spec.goal_world)
        goal.pose.orientation.w = 1.0
        t0 = goal.header.stamp.to_sec()
        self.goal_pub.publish(goal)

        def ended() -> bool:
            s = self._status
            return (
                s is not None
                and s.episode_id == episode_id
                and (s.reached_goal or s.collided or not s.active)
            )

        finished = self._wait(ended, self.episode_timeout_s)
        with self._lock:
            self._recording = False
            status = self._status
            points = np.asarray(self._points, dtype=np.float64).reshape(-1, 4)
            decisions = list(self._decisions)
            timings = list(self._timings)
            boxes = list(self._boxes)
        t_end = rospy.Time.now().to_sec()
        if not finished:
            res = self._result(spec, "timeout", f"no goal within {self.episode_timeout_s} s")
        elif status.reached_goal:
            res = self._result(spec, "goal_reached", status.reason)
            res.time_to_goal_s = status.sim_time.to_sec() - t0
        elif status.collided:
            res = self._result(spec, "collision", status.reason)
        else:
            res = self._result(spec, "timeout", f"episode ended: {status.reason}")
        res.flight_time_s = t_end - t0
        res.path_length_m = path_length(points[:, 1:])
        res.min_clearance_m = clearance_lower_bound(points[:, 1:], boxes, self.vehicle_box_m)
        if len(points):
            keep = np.unique(np.floor((points[:, 0] - points[0, 0]) * 10.0), return_index=True)[1]
            res.trajectory = points[keep].round(4).tolist()
        decided = [d for d in decisions if d.status == "decided"]
        if decided:
            res.decisions = len(decided)
            res.decision_ms = [round(d.decision_ms, 4) for d in decided]
        elif timings:
            res.decisions = len(timings)
            res.decision_ms = [round(t.map_update_ms + t.total_ms, 4) for t in timings]
        if decisions:
            last = decisions[-1]
            res.counts = dict(zip(last.count_names, (int(v) for v in last.count_values), strict=True))
            res.tracker_rejections = int(last.tracker_rejections)
        return res


def wait_for_param(name: str, timeout_s: float) -> bool:
    """True once the ROS master holds the parameter (polled every 0.1 s, wall clock)."""
    import rosgraph

    master = rosgraph.Master("/eval_runner_probe")
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            if master.hasParam(name):
                return True
        except OSError:  # the master is not up yet
            pass
        time.sleep(0.1)
    return False


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", required=True, help="episodes.json (evaluation.episodes.write_episodes)")
    ap.add_argument("--controller", required=True, choices=["expert", "py", "cpp"])
    ap.add_argument("--out", required=True, help="results file (JSON lines, appended)")
    ap.add_argument("--episode-timeout-s", type=float, default=60.0)
    ap.add_argument("--takeoff-timeout-s", type=float, default=20.0)
    ap.add_argument("--vehicle-box-m", default="0.25,0.25,0.25")
    ap.add_argument(
        "--no-reset",
        action="store_true",
        help="one episode, the one the simulator runs since its start (its config holds seed, start, goal)",
    )
    args = ap.parse_args(rospy.myargv(argv if argv is not None else sys.argv)[1:])
    # rospy reads /use_sim_time once, in init_node: wait until the launch file has set it (the runner may
    # start before roslaunch has set its parameters), or every wait below would run on the wall clock.
    if not wait_for_param("/use_sim_time", 60.0):
        print("[eval] /use_sim_time is not set: is the simulator's launch running?", file=sys.stderr)
        return 1
    rospy.init_node(f"eval_runner_{args.controller}", disable_signals=False)
    box = tuple(float(x) for x in args.vehicle_box_m.split(","))
    runner = EpisodeRunner(args.controller, args.episode_timeout_s, args.takeoff_timeout_s, box)
    specs = read_episodes(args.episodes)
    if args.no_reset and len(specs) != 1:
        print("[eval] --no-reset flies exactly one episode", file=sys.stderr)
        return 1
    for spec in specs:
        if rospy.is_shutdown():
            return 1
        wall0 = time.monotonic()
        res = runner.run(spec, reset=not args.no_reset)
        append_result(args.out, res)
        print(
            f"[eval {args.controller}] episode {spec.index} seed {spec.seed}: {res.outcome} ({res.reason}); "
            f"{res.flight_time_s:.1f} s sim, {time.monotonic() - wall0:.1f} s wall, "
            f"{res.decisions} decisions",
            file=sys.stderr,
            flush=True,
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
