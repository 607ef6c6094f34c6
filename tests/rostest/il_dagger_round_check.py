#!/usr/bin/env python3
"""rostest node of il_dagger_round.test: waits for the imitation collector's manifest (written when its two
episodes are done) and checks one DAgger round with beta = 0: the learner flew, the expert labelled exactly
the frames the learner saw (label start time = observation stamp), every record is a DEMO labelled by the
expert, the episode files are complete and convert to the trainer's npz contract."""

from __future__ import annotations

import json
import shutil
import time
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest

from quad_il.imitation.convert import collect_records, records_to_npz_arrays
from quad_il.imitation.dataset import list_episodes, read_episode
from quad_il.imitation.types import Controller, Partition


class DaggerRound(unittest.TestCase):
    def test_one_round(self) -> None:
        data = Path(rospy.get_param("~data_dir"))
        episodes = int(rospy.get_param("~episodes"))
        manifest = data / "collector_manifest.json"
        deadline = time.monotonic() + 140.0
        while not manifest.is_file() and time.monotonic() < deadline and not rospy.is_shutdown():
            time.sleep(0.2)
        self.assertTrue(manifest.is_file(), f"no {manifest}: the collector did not finish its episodes")
        m = json.loads(manifest.read_text())
        self.assertFalse(m["interrupted"])
        self.assertEqual(m["episodes"], episodes)
        stats = m["stats"]
        self.assertGreater(stats["steps_learner"], 0, m)
        # beta = 0: the expert flies only on frames without a learner plan.
        self.assertLessEqual(stats["steps_expert"], stats["missing_learner"], m)
        self.assertGreater(m["records"], 20, m)
        self.assertEqual(m["records"], stats["records"]["demo"])
        files, partial = list_episodes(data)
        self.assertEqual(partial, [])
        self.assertGreaterEqual(len(files), 1)
        n = 0
        for f in files:
            recs = read_episode(f)
            n += len(recs)
            for r in recs:
                self.assertEqual(r.partition, Partition.DEMO)
                self.assertEqual(r.source, "expert")
                self.assertIn(r.controller, (Controller.LEARNER, Controller.EXPERT))
                # The label was planned from exactly this frame (lockstep pairing by stamp).
                self.assertEqual(round(r.label.start_time_s * 1e9), round(r.obs.stamp_s * 1e9))
                self.assertLessEqual(r.obs.odom_stamp_s, r.obs.stamp_s + 1e-9)
                self.assertLess(r.obs.stamp_s - r.obs.odom_stamp_s, 0.0051)
                self.assertIsNotNone(r.obs.depth_m)
            flown = [r.controller for r in recs]
            self.assertGreater(flown.count(Controller.LEARNER), 0)
        self.assertEqual(n, m["records"])
        records, _ = collect_records([data])
        arrays = records_to_npz_arrays(records)
        self.assertEqual(len(arrays), n)
        self.assertTrue(np.isfinite(arrays.bspline_ctrl_world).all())
        shutil.rmtree(data.parent, ignore_errors=True)  # about 0.3 MB per record (depth at 320 x 240)


if __name__ == "__main__":
    rospy.init_node("il_dagger_round_check")
    rostest.rosrun("quad_il", "il_dagger_round", DaggerRound)
