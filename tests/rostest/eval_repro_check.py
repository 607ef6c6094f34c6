#!/usr/bin/env python3
"""rostest node: two runs of the closed-loop evaluation on the same episode fly the same way.

The episode runner is a lockstep depth consumer (quad_il.lockstep): it takes off, gives the goal and ends the
episode at held frames, and the policy nodes wait for their frame's odometry and for the tracker to take each
trajectory before they acknowledge the frame. So a deterministic controller must fly an episode bit for bit
the same in every run, whatever the load. Checked for the expert, the C++ and the Python policy node (a
goal-seeking test policy, GoalLinePolicy, with config/policy_recovery.yaml, so refusals and recoveries happen
on the way, on an 8-10 m episode): identical 10 Hz trajectories, outcomes, path lengths and decision counts;
every controller reaches the goal (the goal-line policy with the recovery is a pilot that does, so a broken
wrapper or wiring fails here); the policy nodes refused and recovered on the way; no lockstep acknowledgement
or command wait timed out (the start-up race of a late consumer costs a whole lockstep timeout).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import unittest
from pathlib import Path

import rostest

from quad_il.inference.random_policy import export_goal_line_policy

ROOT = Path(__file__).resolve().parents[2]
CONTROLLERS = ("expert", "cpp", "py")
STALLS = ("not acknowledged by", "no command stamped")


def run_eval(policy: Path, out: Path) -> subprocess.CompletedProcess:
    cmd = [
        sys.executable,
        "-m",
        "quad_il.evaluation.run_eval",
        "--policy",
        str(policy),
        "--policy-config",
        str(ROOT / "config" / "policy_recovery.yaml"),
        "--seeds",
        "9001",
        "--episodes",
        "1",
        "--controllers",
        ",".join(CONTROLLERS),
        "--episode-timeout-s",
        "15",
        "--min-distance-m",
        "8",
        "--max-distance-m",
        "10",
        "--out",
        str(out),
        "--backend",
        "ros",  # the ROS nodes' lockstep reproducibility (the engine's parity: tests/python/test_engine_*)
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=800)


class EvalReproTest(unittest.TestCase):
    def test_two_runs_fly_the_same_episode_identically(self) -> None:
        tmp = Path(tempfile.mkdtemp(prefix="eval_repro_"))
        policy = export_goal_line_policy(tmp / "goal_line.ts")
        results = []
        for run in ("a", "b"):
            proc = run_eval(policy, tmp / run)
            self.assertEqual(proc.returncode, 0, proc.stderr[-3000:])
            results.append(
                {
                    c: [json.loads(line) for line in (tmp / run / f"{c}.jsonl").read_text().splitlines()]
                    for c in CONTROLLERS
                }
            )
            for log in sorted((tmp / run / "logs").glob("*_launch.log")):
                text = log.read_text(errors="replace")
                for stall in STALLS:
                    self.assertNotIn(stall, text, f"{log.name}: a lockstep wait timed out")
        a, b = results
        # Both runs are pinned to the same policy, node config, simulator config and commit.
        pins = [json.loads((tmp / run / "pin.json").read_text()) for run in ("a", "b")]
        self.assertEqual(pins[0], pins[1])
        self.assertEqual(pins[0]["tier"], "shield")
        for c in CONTROLLERS:  # (no subTest: rosunit's XML runner reports a test with subtests as failed)
            self.assertEqual((len(a[c]), len(b[c])), (1, 1), f"{c}: {a[c]} / {b[c]}")
            ra, rb = a[c][0], b[c][0]
            self.assertEqual(ra["outcome"], "goal_reached", f"{c}: {ra['reason']}")
            self.assertGreater(ra["path_length_m"], 5.0, f"{c}: the vehicle hardly moved")
            self.assertGreater(len(ra["trajectory"]), 20, c)
            for key in ("outcome", "trajectory", "path_length_m", "decisions", "counts"):
                self.assertEqual(ra[key], rb[key], f"{c}: {key} differs between the two runs")
            if c != "expert":
                self.assertGreater(ra["counts"].get("accepted", 0), 10, f"{c}: {ra['counts']}")
                self.assertGreater(ra["counts"].get("recovered", 0), 0, f"{c}: no recovery on the way")
        # Reached only when every check passed: a failing run keeps its logs for inspection.
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    rostest.rosrun("quad_il", "eval_repro", EvalReproTest)
