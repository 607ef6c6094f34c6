#!/usr/bin/env python3
"""rostest node of il_dagger_round.test: waits for the imitation collector's manifest (written when its two
episodes are done) and checks one DAgger round with beta = 0: the learner flew, the expert labelled exactly
the frames the learner saw (label start time = observation stamp), every record is a DEMO labelled by the
expert, the round's dataset is complete and converts to the trainer's npz contract."""

from __future__ import annotations

import shutil
import unittest
from pathlib import Path

import rospy
import rostest
from il_round_common import check_converts, episode_records, wait_for_manifest

from quad_il.imitation.types import Controller, Partition


class DaggerRound(unittest.TestCase):
    def test_one_round(self) -> None:
        data = Path(rospy.get_param("~data_dir"))
        m = wait_for_manifest(self, data, int(rospy.get_param("~episodes")))
        stats = m["stats"]
        self.assertGreater(stats["steps_learner"], 0, m)
        # beta = 0: the expert flies only on frames without a learner plan.
        self.assertLessEqual(stats["steps_expert"], stats["missing_learner"], m)
        self.assertGreater(m["records"], 20, m)
        self.assertEqual(m["records"], stats["records"]["demo"])
        episodes = episode_records(self, data)
        n = sum(len(recs) for recs in episodes)
        for recs in episodes:
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
        check_converts(self, data, n)
        shutil.rmtree(data.parent, ignore_errors=True)  # about 0.3 MB per record (depth at 320 x 240)


if __name__ == "__main__":
    rospy.init_node("il_dagger_round_check")
    rostest.rosrun("quad_il", "il_dagger_round", DaggerRound)
