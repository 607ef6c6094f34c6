"""What a closed-loop evaluation's failures are, by kind (issue 33), from a run_eval output directory.

    python -m quad_il.evaluation.failures results/X [--controller cpp] [--csv FILE] [--near-goal-m 3]

Every episode that did not reach its goal gets one kind, from its outcome, its 10 Hz trajectory and its goal
(thresholds are options):
| kind | rule |
|---|---|
| collision_near_goal | a collision within --near-goal-m of the goal |
| collision_moving | a collision elsewhere at --slow-mps or more (mean speed over the last second) |
| collision_slow | a collision elsewhere below --slow-mps: drifted or crept into the obstacle |
| timeout_circling | a timeout ending within --near-goal-m of the goal: the goal was reached for, not hit |
| timeout_stuck | a timeout elsewhere, having moved less than --stuck-m over the last --window-s |
| timeout_creeping | any other timeout: moving, but not reaching the goal in time |
| reset_failed, takeoff_failed | as the outcome says (not the policy's doing) |

Prints a Markdown table of the counts (share of all episodes with 95 % Wilson intervals); --csv writes one row
per failed episode (index, seed, kind, outcome, distance to the goal at the end, final speed, reason). Exit
status 2 when the directory is not a complete evaluation.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from quad_il.evaluation.compare import CompareError, load_run
from quad_il.evaluation.episodes import EpisodeResult, EpisodeSpec
from quad_il.evaluation.stats import format_rate
from quad_il.tools.cli import HelpFormatter

KINDS = (
    "collision_near_goal",
    "collision_moving",
    "collision_slow",
    "timeout_circling",
    "timeout_stuck",
    "timeout_creeping",
    "reset_failed",
    "takeoff_failed",
)


@dataclass(frozen=True)
class Thresholds:
    near_goal_m: float = 3.0
    slow_mps: float = 0.5
    stuck_m: float = 1.0
    window_s: float = 10.0


@dataclass(frozen=True)
class Failure:
    index: int
    seed: int
    kind: str
    outcome: str
    goal_distance_m: float  # at the end of the trajectory (nan without one)
    final_speed_mps: float  # mean over the last second (nan without two samples)
    reason: str


def _speed(traj: np.ndarray, span_s: float) -> float:
    if len(traj) < 2:
        return math.nan
    t_end = traj[-1, 0]
    seg = traj[traj[:, 0] >= t_end - span_s]
    if len(seg) < 2:
        seg = traj[-2:]
    dt = seg[-1, 0] - seg[0, 0]
    return float(np.linalg.norm(seg[-1, 1:4] - seg[0, 1:4]) / dt) if dt > 0 else math.nan


def classify(result: EpisodeResult, spec: EpisodeSpec, th: Thresholds | None = None) -> Failure | None:
    """The failure kind of one episode; None when it reached its goal."""
    th = th or Thresholds()
    if result.outcome == "goal_reached":
        return None
    traj = np.asarray(result.trajectory, dtype=float).reshape(-1, 4)
    goal = np.asarray(spec.goal_world, dtype=float)
    d_goal = float(np.linalg.norm(traj[-1, 1:4] - goal)) if len(traj) else math.nan
    speed = _speed(traj, 1.0)
    kind = result.outcome
    if result.outcome == "collision":
        if d_goal <= th.near_goal_m:
            kind = "collision_near_goal"
        elif not math.isnan(speed) and speed >= th.slow_mps:
            kind = "collision_moving"
        else:
            kind = "collision_slow"
    elif result.outcome == "timeout":
        if d_goal <= th.near_goal_m:
            kind = "timeout_circling"
        else:
            window = traj[traj[:, 0] >= traj[-1, 0] - th.window_s] if len(traj) else traj
            moved = (
                float(np.max(np.linalg.norm(window[:, 1:4] - window[-1, 1:4], axis=1)))
                if len(window)
                else 0.0
            )
            kind = "timeout_stuck" if moved < th.stuck_m else "timeout_creeping"
    return Failure(result.index, result.seed, kind, result.outcome, d_goal, speed, result.reason)


def failures_of(run: str | Path, controller: str = "cpp", th: Thresholds | None = None) -> tuple[int, list]:
    """(episodes, failures) of one complete run_eval output directory; CompareError when it is not one."""
    th = th or Thresholds()
    specs, results = load_run(Path(run), controller)
    by_index = {s.index: s for s in specs}
    out = [f for r in results.values() if (f := classify(r, by_index[r.index], th)) is not None]
    return len(results), sorted(out, key=lambda f: f.index)


def table(episodes: int, failures: list[Failure]) -> str:
    rows = ["| failure kind | episodes | share of all episodes [95 % CI] |", "|---|---|---|"]
    for k in KINDS:
        n = sum(f.kind == k for f in failures)
        if n:
            rows.append(f"| {k} | {n} | {format_rate(n, episodes)} |")
    rows.append(f"| all failures | {len(failures)} | {format_rate(len(failures), episodes)} |")
    return "\n".join(rows) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.evaluation.failures", formatter_class=HelpFormatter, description=__doc__
    )
    ap.add_argument("run", help="a run_eval output directory")
    ap.add_argument("--controller", default="cpp", help="whose results: expert, cpp or py")
    ap.add_argument("--csv", default=None, help="write one row per failed episode here")
    d = Thresholds()
    ap.add_argument("--near-goal-m", type=float, default=d.near_goal_m, help="near the goal: within this (m)")
    ap.add_argument(
        "--slow-mps", type=float, default=d.slow_mps, help="slower than this at a collision (m/s)"
    )
    ap.add_argument("--stuck-m", type=float, default=d.stuck_m, help="stuck: moved less than this (m) ...")
    ap.add_argument("--window-s", type=float, default=d.window_s, help="... over the last this many seconds")
    a = ap.parse_args(argv)
    th = Thresholds(a.near_goal_m, a.slow_mps, a.stuck_m, a.window_s)
    try:
        episodes, fails = failures_of(a.run, a.controller, th)
    except CompareError as e:
        print(f"failures: error: {e}", file=sys.stderr)
        return 2
    print(f"{a.run} ({a.controller}): {episodes} episodes, {len(fails)} failed")
    print(table(episodes, fails), end="")
    if a.csv:
        with open(a.csv, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["index", "seed", "kind", "outcome", "goal_distance_m", "final_speed_mps", "reason"])
            for x in fails:
                w.writerow(
                    [
                        x.index,
                        x.seed,
                        x.kind,
                        x.outcome,
                        f"{x.goal_distance_m:.3f}",
                        f"{x.final_speed_mps:.3f}",
                        x.reason,
                    ]
                )
    return 0


if __name__ == "__main__":
    sys.exit(main())
