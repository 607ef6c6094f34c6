#!/usr/bin/env python3
"""rostest node of il_mega_round.test: waits for the imitation collector's manifest and checks one MEGA-DAgger
round with two experts in the loop (the simulator waited for both experts' acknowledgements, and the collector
paired both experts' plans with each frame the learner saw, else the learner raises): the gate handed control
to an expert, every record is an INTERVENTION labelled by expert_a or expert_b from exactly its frame, with a
finite score and a clearance above the safety threshold, the collector received the worlds' voxel maps, and
the round's dataset is complete and converts to the trainer's npz contract."""

from __future__ import annotations

import shutil
import unittest
from pathlib import Path

import numpy as np
import rospy
import rostest
from il_round_common import check_converts, episode_records, wait_for_manifest

from quad_il.imitation.types import Controller, Partition


class MegaRound(unittest.TestCase):
    def test_one_round(self) -> None:
        data = Path(rospy.get_param("~data_dir"))
        m = wait_for_manifest(self, data, int(rospy.get_param("~episodes")))
        self.assertEqual(m["round_config"]["algorithm"]["name"], "mega_dagger")
        stats = m["stats"]
        self.assertGreater(stats["interventions"], 0, m)
        self.assertGreater(stats["steps_expert"], 0, m)
        # The collector starts with the current world's map and takes each later world's.
        self.assertGreaterEqual(m["collector"]["voxel_maps"], 1, m)
        self.assertGreater(m["records"], 5, m)
        self.assertEqual(m["records"], stats["records"]["intervention"])
        episodes = episode_records(self, data)
        n = sum(len(recs) for recs in episodes)
        for recs in episodes:
            for r in recs:
                self.assertEqual(r.partition, Partition.INTERVENTION)
                self.assertIn(r.source, ("expert_a", "expert_b"))
                self.assertEqual(r.controller, Controller.EXPERT)
                self.assertEqual(round(r.label.start_time_s * 1e9), round(r.obs.stamp_s * 1e9))
                self.assertTrue(np.isfinite(r.score))
                self.assertGreaterEqual(r.min_clearance_m, 0.3)  # the safety filter's threshold
        self.assertEqual(n, m["records"])
        check_converts(self, data, n)
        shutil.rmtree(data.parent, ignore_errors=True)


if __name__ == "__main__":
    rospy.init_node("il_mega_round_check")
    rostest.rosrun("quad_il", "il_mega_round", MegaRound)
