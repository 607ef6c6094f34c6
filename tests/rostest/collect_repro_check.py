#!/usr/bin/env python3
"""rostest node: two short lockstep collections with the same seeds give identical records.

Each run is a whole `roslaunch quad_il collect.launch` on its own master (1 episode, seed 4, a goal 15-18 m
away: tests/rostest/collect_test.yaml). Checks: both datasets complete and valid; identical record contents
apart from the wall-clock timing fields (and the CRC covering them); |odom stamp - depth stamp| <= one
odometry period (5 ms at 200 Hz) in every record; the first run's rosbag (record_bag:=true), read with the
PyPI rosbags library, holds every recorded B-spline exactly and the goal; a second launch into the same
directory is refused with a clear error before anything starts.
"""

from __future__ import annotations

import shutil
import tempfile
import unittest
from pathlib import Path

import numpy as np
import rostest

from quad_il.collection.compare import compare_records, dataset_records, stamp_gaps_s
from quad_il.collection.episodes import EpisodeLog
from quad_il.collection.launch_run import run_collect

HERE = Path(__file__).resolve().parent
ODOM_PERIOD_S = 0.005
LAUNCH_ARGS = {
    "collect_config": HERE / "collect_test.yaml",
    "seeds": "4",
    "episodes": 1,
    "output": "log",
}


class CollectReproTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        cls.tmp = Path(tempfile.mkdtemp(prefix="collect_repro_"))
        cls.runs = []
        for name, extra in (("a", {"record_bag": "true"}), ("b", {})):
            run = run_collect(cls.tmp / name, cls.tmp / f"{name}.log", timeout_s=70.0, **LAUNCH_ARGS, **extra)
            cls.runs.append(run)

    @classmethod
    def tearDownClass(cls) -> None:
        shutil.rmtree(cls.tmp, ignore_errors=True)

    def _log_tail(self, i: int) -> str:
        return "\n".join(self.runs[i].log.splitlines()[-40:])

    def test_1_runs_complete(self) -> None:
        for i, run in enumerate(self.runs):
            manifest = (run.out_dir / "manifest.yaml").read_text()
            self.assertIn("status: complete", manifest, self._log_tail(i))
            episodes = EpisodeLog.read(run.out_dir / "episodes.csv")
            self.assertEqual(len(episodes), 1, self._log_tail(i))
            self.assertEqual(episodes[0].outcome, "goal_reached", self._log_tail(i))
            self.assertIn("[collect] episode 1/1 seed 4: goal_reached", run.log)
            self.assertNotIn("lockstep timeouts", run.log, self._log_tail(i))

    def test_2_identical_records(self) -> None:
        a = dataset_records(self.runs[0].out_dir)
        b = dataset_records(self.runs[1].out_dir)
        self.assertGreater(len(a), 3)
        problems = compare_records(a, b)
        self.assertEqual(problems, [], "\n".join(problems))
        # The timings are real measurements (not zero), which is why they are excluded.
        self.assertTrue(np.all(a["t_total_ms"] > 0))

    def test_3_depth_odom_synchronised(self) -> None:
        for run in self.runs:
            recs = dataset_records(run.out_dir)
            gaps = stamp_gaps_s(recs)
            self.assertLessEqual(float(gaps.max()), ODOM_PERIOD_S + 1e-9, f"gaps {np.sort(gaps)[-5:]}")
            # Each record's plan time is at or after the depth frame it used.
            self.assertTrue(np.all(recs["sim_time_s"] >= recs["depth_stamp_s"] - 1e-9))

    def test_4_rosbag_read_with_rosbags(self) -> None:
        from rosbags.highlevel import AnyReader

        bag = self.runs[0].out_dir / "collect.bag"
        self.assertTrue(bag.is_file(), self._log_tail(0))
        recs = dataset_records(self.runs[0].out_dir)
        splines: dict[int, np.ndarray] = {}
        goals = []
        counts: dict[str, int] = {}
        with AnyReader([bag]) as reader:
            for conn, _, raw in reader.messages():
                counts[conn.topic] = counts.get(conn.topic, 0) + 1
                if conn.topic == "/planner/bspline":
                    m = reader.deserialize(raw, conn.msgtype)
                    splines[int(m.traj_id)] = np.array([[p.x, p.y, p.z] for p in m.pos_pts])
                elif conn.topic == "/planner/goal":
                    m = reader.deserialize(raw, conn.msgtype)
                    goals.append((m.pose.position.x, m.pose.position.y, m.pose.position.z))
        for topic in ("/odom", "/sim/status", "/planner/timing", "/so3_cmd"):
            self.assertGreater(counts.get(topic, 0), 0, f"{topic} missing from the bag: {counts}")
        self.assertEqual(len(goals), 1)
        np.testing.assert_array_equal(np.array(goals[0]), recs["goal_world"][0])
        for r in recs:
            n = int(r["num_ctrl_pts"])
            tid = int(r["bspline_traj_id"])
            self.assertIn(tid, splines, f"trajectory {tid} of the dataset is not in the bag")
            np.testing.assert_array_equal(splines[tid], r["ctrl_pts_world"][:n])

    def test_5_existing_dataset_refused(self) -> None:
        before = sorted(p.name for p in self.runs[1].out_dir.iterdir())
        run = run_collect(self.runs[1].out_dir, self.tmp / "refused.log", timeout_s=30.0, **LAUNCH_ARGS)
        self.assertNotEqual(run.returncode, 0)
        self.assertIn("already holds a dataset", run.log)
        self.assertIn("pass another output_dir:=DIR", run.log)
        self.assertNotIn("started with pid", run.log)  # refused while parsing: no node was started
        self.assertEqual(sorted(p.name for p in self.runs[1].out_dir.iterdir()), before)


if __name__ == "__main__":
    rostest.rosrun("quad_il", "collect_repro", CollectReproTest)
