#!/usr/bin/env python3
"""rostest node: the ROS master killed during `roslaunch quad_il collect.launch`, then the run resumed.

Issue 30, fault table "ROS master killed during collect.launch". Starts collect.launch (2 episodes of
tests/rostest/collect_test.yaml, seeds 4 and 5, resume:=true so that the first run and its resumption are the
same command) on its own master, waits until the first episode is finished (its row in episodes.csv) and the
second one has recorded (records on disk beyond the first episode's), kills rosmaster with SIGKILL and checks
that the finished episode's records are intact and readable (Python and C++ readers). Then runs the same
command again: it must cut the interrupted episode's records, fly the missing episode, and leave one complete
dataset in which the first episode's records are byte-identical to those on disk before the resume.

Keyed episodes (issue 32): the same two episodes flown straight, in one launch, give records identical (all
fields but the wall-clock timings) to the resumed dataset's, episode 1 included, which the resumed run flew
in a new launch right after the simulator's start: an episode's stamps, id and flight depend only on its key.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
import time
import unittest
from pathlib import Path

import numpy as np
import psutil
import rostest
import yaml
from collect_crash_check import records_on_disk

from quad_il.collection.compare import compare_records, dataset_records, records_digest
from quad_il.collection.episodes import EpisodeLog, load_collect_config, plan_episode
from quad_il.collection.launch_run import run_collect, start_collect, stop
from quad_il.data.shards import load_dataset, open_dataset
from quad_il.data.synthetic import find_collector_tool

HERE = Path(__file__).resolve().parent
LAUNCH_ARGS = {
    "collect_config": HERE / "collect_test.yaml",
    "seeds": "4,5",
    "episodes": 2,
    "output": "log",
    "resume": "true",
}


def finished_rows(out: Path) -> list:
    path = out / "episodes.csv"
    return EpisodeLog.read(path) if path.exists() else []


def goal_of(index: int) -> np.ndarray:
    cfg = load_collect_config(HERE / "collect_test.yaml", {"seeds": [4, 5], "episodes": 2})
    return np.asarray(plan_episode(cfg, index).goal_world)


class CollectMasterKillTest(unittest.TestCase):
    def test_master_killed_then_resumed(self) -> None:
        tmp = Path(tempfile.mkdtemp(prefix="collect_master_kill_"))
        out = tmp / "ds"
        try:
            proc, _ = start_collect(out, tmp / "run1.log", **LAUNCH_ARGS)
            try:
                deadline = time.monotonic() + 90.0
                while True:
                    rows = finished_rows(out)
                    if rows and records_on_disk(out) > rows[0].samples:
                        break
                    self.assertIsNone(proc.poll(), (tmp / "run1.log").read_text()[-3000:])
                    self.assertLess(
                        time.monotonic(), deadline, "episode 1 not finished / episode 2 not recording"
                    )
                    time.sleep(0.05)
                masters = [
                    p
                    for p in psutil.Process(proc.pid).children(recursive=True)
                    if "rosmaster" in " ".join(p.cmdline())
                ]
                self.assertEqual(len(masters), 1, masters)
                os.kill(masters[0].pid, signal.SIGKILL)
                proc.wait(timeout=60)  # roslaunch shuts every node down when its master dies
            finally:
                stop(proc)
            log1 = (tmp / "run1.log").read_text(errors="replace")
            self.assertIn("[master] has died", log1)

            # The finished episode: its row, and exactly its records, intact and readable.
            rows = finished_rows(out)
            self.assertEqual([r.index for r in rows], [0], log1[-3000:])
            ds = open_dataset(out)
            report = ds.verify()
            self.assertEqual(report.errors, [], report.format())
            recs = load_dataset(out).records
            first = recs[np.all(recs["goal_world"] == goal_of(0), axis=1)]
            self.assertGreater(len(first), 0)
            self.assertEqual(len(first), rows[0].samples)
            np.testing.assert_array_equal(first["seq"], np.arange(len(first)))
            self.assertGreater(len(recs), len(first))  # the interrupted episode had started recording
            before = first.tobytes()
            verify = subprocess.run(
                [str(find_collector_tool("read_dataset")), "verify", str(out)], capture_output=True, text=True
            )
            self.assertIn(verify.returncode, (0, 3), verify.stdout + verify.stderr)
            summary = yaml.safe_load((out / "collect_summary.yaml").read_text())
            self.assertFalse(summary["complete"], summary)

            # The same command again completes the run.
            run = run_collect(out, tmp / "run2.log", timeout_s=90.0, **LAUNCH_ARGS)
            self.assertEqual(run.returncode, 0, run.log[-3000:])
            self.assertIn("collect.launch: resume: truncate: shard_000000.qdr: cut after record", run.log)
            self.assertIn("resuming after 1 finished episodes", run.log)
            rows = finished_rows(out)
            self.assertEqual([r.index for r in rows], [0, 1], run.log[-3000:])
            ds = open_dataset(out)
            self.assertEqual(ds.status, "complete")
            report = ds.verify()
            self.assertEqual((report.errors, report.warnings), ([], []), report.format())
            recs = load_dataset(out).records
            self.assertEqual(len(recs), rows[0].samples + rows[1].samples)
            np.testing.assert_array_equal(recs["seq"], np.arange(len(recs)))
            first, second = recs[: rows[0].samples], recs[rows[0].samples :]
            self.assertEqual(first.tobytes(), before)  # the finished episode untouched
            self.assertTrue(np.all(second["goal_world"] == goal_of(1)))
            keys = {(int(r["world_seed"]), int(r["episode_id"])) for r in recs}
            self.assertEqual(len(keys), 2, keys)  # one (world_seed, episode_id) per episode
            self.assertEqual([e["records"] for e in ds.manifest["episodes"]], [r.samples for r in rows])
            summary = yaml.safe_load((out / "collect_summary.yaml").read_text())
            self.assertTrue(summary["complete"], summary)
            self.assertEqual((summary["resumed_at_episode"], summary["episodes"]), (1, 2))
            # Keyed: episode i has id i + 1 and starts at 1 s + (i + 1) * 1000 s of sim time.
            self.assertEqual(first["episode_id"].tolist(), [1] * len(first))
            self.assertEqual(second["episode_id"].tolist(), [2] * len(second))
            self.assertTrue(np.all((first["sim_time_s"] >= 1001.0) & (first["sim_time_s"] < 2001.0)))
            self.assertTrue(np.all((second["sim_time_s"] >= 2001.0) & (second["sim_time_s"] < 3001.0)))

            # The same episodes flown straight in one launch: the same records (but the CPU timings).
            run = run_collect(tmp / "straight", tmp / "straight.log", timeout_s=90.0, **LAUNCH_ARGS)
            self.assertEqual(run.returncode, 0, run.log[-3000:])
            resumed, straight = dataset_records(out), dataset_records(tmp / "straight")
            problems = compare_records(resumed, straight)
            self.assertEqual(problems, [], "\n".join(problems))
            n0 = rows[0].samples
            self.assertEqual(records_digest(resumed[n0:]), records_digest(straight[n0:]))
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    rostest.rosrun("quad_il", "collect_master_kill", CollectMasterKillTest)
