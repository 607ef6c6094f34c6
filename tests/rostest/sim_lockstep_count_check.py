#!/usr/bin/env python3
"""rostest node of sim_lockstep_count.test: the episode runner records the lockstep timeouts of its episode.

Starts quad_sim in lockstep with a 0.3 s timeout and the consumers `count_controller` (the scripted
controller, which leaves its 5th, 10th and 15th depth frames unacknowledged) and `eval_runner`, then flies one
episode with the evaluation's EpisodeRunner (take-off, goal, a 1 s episode timeout). The result must count
exactly those 3 timeouts. A second episode through the simulator's reset service (the controller acknowledges
all of its frames) must count 0: the simulator's counts are for its whole run, the runner's for the episode.
"""

import subprocess
import tempfile
import unittest
from pathlib import Path

import rospy
import rostest
import yaml

from quad_il.collection.episodes import EpisodeSpec
from quad_il.evaluation.runner import EpisodeRunner

SKIPPED = 3  # frames count_controller leaves unacknowledged (its ~skip_frames)


class RunnerCountTest(unittest.TestCase):
    def test_runner_counts_the_episodes_lockstep_timeouts(self) -> None:
        rospy.init_node("sim_lockstep_count_check")
        cfg = yaml.safe_load(Path(rospy.get_param("~base_config")).read_text())
        base_dir = Path(rospy.get_param("~base_config")).parent
        cfg["vehicle_file"] = str((base_dir / cfg["vehicle_file"]).resolve())
        cfg["lockstep"]["depth_consumers"] = ["count_controller", "eval_runner"]
        cfg["lockstep"]["wait_for_command"] = True
        cfg["lockstep"]["timeout_s"] = 0.3
        spec = EpisodeSpec(0, int(cfg["world"]["seed"]), (-18.0, 0.0, 1.0), 0.0, (18.0, 0.0, 1.5))
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "sim.yaml"
            path.write_text(yaml.safe_dump(cfg))
            sim = subprocess.Popen(
                ["rosrun", "quad_sim", "quad_sim_node", f"_config:={path}", "_world_seed:=-1"]
                + ["__name:=quad_sim"],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.STDOUT,
            )
            try:
                runner = EpisodeRunner(
                    "expert",
                    episode_timeout_s=1.0,
                    takeoff_timeout_s=20.0,
                    consumer="eval_runner",
                    controller_consumer="count_controller",
                )
                res = runner.run(spec, reset=False)
                res2 = runner.run(spec, reset=True)
            finally:
                sim.terminate()
                sim.wait(20)
        self.assertEqual(res.outcome, "timeout", res.reason)  # hovering at the start: no goal within 1 s
        self.assertEqual(res.lockstep_timeouts, SKIPPED, res)
        self.assertEqual(res2.outcome, "timeout", res2.reason)
        self.assertEqual(res2.lockstep_timeouts, 0, res2)


if __name__ == "__main__":
    rostest.rosrun("quad_il", "sim_lockstep_count", RunnerCountTest)
