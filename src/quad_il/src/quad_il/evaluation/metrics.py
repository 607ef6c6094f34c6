"""Clearance geometry and per-controller summaries of evaluation results (ROS-free)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from quad_il.evaluation.episodes import OUTCOMES, EpisodeResult

FloatArray = NDArray[np.float64]

# The safety layer's refusal names (inference.core.VERDICT_LABELS other than "accepted").
REFUSAL_NAMES = frozenset(
    {
        "non_finite_output",
        "velocity_limit",
        "acceleration_limit",
        "start_far_from_vehicle",
        "collision_in_depth",
    }
)


@dataclass(frozen=True)
class Box:
    """An oriented world box (the simulator's world markers): centre, rotation (x, y, z, w), full edge
    lengths."""

    center: FloatArray
    q_xyzw: FloatArray
    size: FloatArray


def point_box_distances(points: FloatArray, boxes: Sequence[Box]) -> FloatArray:
    """(N,) exact distance from each point to the nearest box (0 inside); +inf without boxes."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    best = np.full(len(pts), np.inf)
    for b in boxes:
        local = (pts - b.center) @ Rotation.from_quat(b.q_xyzw).as_matrix()  # rows: R^T (p - c)
        excess = np.maximum(np.abs(local) - 0.5 * np.asarray(b.size), 0.0)
        best = np.minimum(best, np.linalg.norm(excess, axis=1))
    return best


def clearance_lower_bound(points: FloatArray, boxes: Sequence[Box], vehicle_box_m: FloatArray) -> float:
    """Minimum over the points of (distance from the vehicle's centre to the nearest box) minus the vehicle
    box's circumscribed radius: a lower bound of the exact box-to-box clearance (the simulator's
    ClearanceToObstacles), negative when the vehicle may touch a box. The ground is not an obstacle here."""
    if len(points) == 0:
        return math.nan
    radius = 0.5 * float(np.linalg.norm(vehicle_box_m))
    return float(point_box_distances(points, boxes).min() - radius)


def path_length(points: FloatArray) -> float:
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum()) if len(p) > 1 else 0.0


def percentile(values: Sequence[float], q: float) -> float:
    """Nearest rank (as the inference benchmark); nan for no values."""
    v = sorted(values)
    if not v:
        return math.nan
    return v[min(max(math.ceil(q * len(v)) - 1, 0), len(v) - 1)]


@dataclass(frozen=True)
class ControllerSummary:
    controller: str
    episodes: int
    success_rate: float
    collision_rate: float
    timeout_rate: float
    other_rate: float  # reset or take-off failures (not the controller's doing)
    mean_time_to_goal_s: float  # over successful episodes
    mean_path_length_m: float  # over successful episodes
    min_clearance_m: float  # over all flown episodes
    median_min_clearance_m: float
    decision_ms_median: float
    decision_ms_p99: float
    decisions: int
    refusals: int
    recovered: int = 0  # refused decisions for which the recovery found a plan (config recovery)
    final_approach: int = (
        0  # decisions that sent the trajectory straight to the goal (recovery.final_approach_m)
    )
    kept: int = 0  # decisions that sent nothing, the plan sent before flown on (config keeping), all kinds
    committed: int = 0  # of those, kept because their commitment had not ended (keeping.commit_s)
    # Lockstep waits of the simulator that timed out during the episodes (a run with any is not reproducible:
    # sim time went on without a consumer's acknowledgement); None when the results do not say.
    lockstep_timeouts: int | None = None
    outcomes: dict[str, int] = field(default_factory=dict)  # episodes per outcome (episodes.OUTCOMES)

    def count(self, outcome: str) -> int:
        return self.outcomes.get(outcome, 0)


def summarise(controller: str, results: Sequence[EpisodeResult]) -> ControllerSummary:
    rs = [r for r in results if r.controller == controller]
    n = len(rs)
    if n == 0:
        raise ValueError(f"no results for controller {controller!r}")

    def rate(outcome: str) -> float:
        return sum(r.outcome == outcome for r in rs) / n

    ok = [r for r in rs if r.outcome == "goal_reached"]
    flown = [r.min_clearance_m for r in rs if not math.isnan(r.min_clearance_m)]
    latencies = [x for r in rs for x in r.decision_ms]
    refusals = sum(v for r in rs for k, v in r.counts.items() if k in REFUSAL_NAMES)
    return ControllerSummary(
        controller=controller,
        episodes=n,
        success_rate=rate("goal_reached"),
        collision_rate=rate("collision"),
        timeout_rate=rate("timeout"),
        other_rate=rate("reset_failed") + rate("takeoff_failed"),
        mean_time_to_goal_s=float(np.mean([r.time_to_goal_s for r in ok])) if ok else math.nan,
        mean_path_length_m=float(np.mean([r.path_length_m for r in ok])) if ok else math.nan,
        min_clearance_m=min(flown) if flown else math.nan,
        median_min_clearance_m=float(np.median(flown)) if flown else math.nan,
        decision_ms_median=percentile(latencies, 0.5),
        decision_ms_p99=percentile(latencies, 0.99),
        decisions=sum(r.decisions for r in rs),
        refusals=refusals,
        recovered=sum(r.counts.get("recovered", 0) for r in rs),
        final_approach=sum(r.counts.get("final_approach", 0) for r in rs),
        kept=sum(r.counts.get("kept", 0) + r.counts.get("committed", 0) for r in rs),
        committed=sum(r.counts.get("committed", 0) for r in rs),
        lockstep_timeouts=_lockstep_timeouts(rs),
        outcomes={o: sum(r.outcome == o for r in rs) for o in OUTCOMES},
    )


def _lockstep_timeouts(rs: Sequence[EpisodeResult]) -> int | None:
    known = [getattr(r, "lockstep_timeouts", None) for r in rs]
    if any(k is None for k in known):
        return None
    return int(sum(known))


def boxes_from_markers(markers: Sequence) -> list[Box]:
    """The world's boxes from the simulator's world markers (visualization_msgs/Marker, namespace "boxes")."""
    return [
        Box(
            np.array([m.pose.position.x, m.pose.position.y, m.pose.position.z]),
            np.array(
                [m.pose.orientation.x, m.pose.orientation.y, m.pose.orientation.z, m.pose.orientation.w]
            ),
            np.array([m.scale.x, m.scale.y, m.scale.z]),
        )
        for m in markers
        if m.ns == "boxes" and m.action == m.ADD
    ]


def summarise_flight(
    res: EpisodeResult,
    t0: float,
    t_end: float,
    points: np.ndarray,
    boxes: list[Box],
    vehicle_box_m: np.ndarray,
    decision_ms: list[float],
    plan_ms: list[float],
    counts: dict[str, int] | None = None,
    tracker_rejections: int = 0,
) -> EpisodeResult:
    """Fills `res` with what was recorded between the goal (t0) and the end (t_end), sim time: `points` rows
    [t, x, y, z] of the odometry, the world's boxes, the policy's decision latencies (decided frames) or,
    without any, the expert's plan latencies (map update + plan), and the policy's last counts."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 4)
    if res.outcome == "goal_reached":
        res.time_to_goal_s = t_end - t0
    res.flight_time_s = t_end - t0
    res.path_length_m = path_length(points[:, 1:])
    res.min_clearance_m = clearance_lower_bound(points[:, 1:], boxes, vehicle_box_m)
    if len(points):
        # The trajectory at 10 Hz: the first sample of every 0.1 s cell.
        keep = np.unique(np.floor((points[:, 0] - points[0, 0]) * 10.0), return_index=True)[1]
        res.trajectory = points[keep].round(4).tolist()
    latencies = decision_ms or plan_ms
    if latencies:
        res.decisions = len(latencies)
        res.decision_ms = [round(v, 4) for v in latencies]
    if counts is not None:
        res.counts = dict(counts)
        res.tracker_rejections = int(tracker_rejections)
    return res
