#!/usr/bin/env python3
"""rostest node of sim_missing_param.test: quad_sim_node refuses to start without a required parameter.

Each case starts the node (rosrun, this test's master) under its own name with one parameter left out and
checks that it exits with status 1 and names the missing parameter's resolved key; the complete command line
is the control: with both parameters the node keeps running until it is stopped."""

import subprocess
import time
import unittest

import rospy
import rostest

from quad_msgs.msg import EpisodeStatus

START_TIMEOUT_S = 30.0


def run_node(name: str, args: list[str]) -> subprocess.Popen:
    return subprocess.Popen(
        ["rosrun", "quad_sim", "quad_sim_node", f"__name:={name}", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


class MissingParamTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls) -> None:
        rospy.init_node("sim_missing_param_check")
        cls.config = rospy.get_param("~config")

    def expect_refusal(self, name: str, args: list[str], key: str) -> None:
        proc = run_node(name, args)
        out, _ = proc.communicate(timeout=START_TIMEOUT_S)
        self.assertEqual(proc.returncode, 1, out)
        self.assertIn(f"quad_sim: missing required parameter /{name}/{key}", out)

    def test_without_world_seed_the_node_exits_naming_it(self) -> None:
        self.expect_refusal("sim_no_seed", [f"_config:={self.config}"], "world_seed")

    def test_without_config_the_node_exits_naming_it(self) -> None:
        self.expect_refusal("sim_no_config", ["_world_seed:=-1"], "config")

    def test_with_both_parameters_the_node_runs(self) -> None:
        proc = run_node("sim_complete", [f"_config:={self.config}", "_world_seed:=-1"])
        try:
            # Up once its latched status is out (the initial episode started).
            msg = rospy.wait_for_message("sim/status", EpisodeStatus, timeout=START_TIMEOUT_S)
            self.assertEqual(msg.world_seed, 1)
            self.assertIsNone(proc.poll(), "quad_sim_node exited although both parameters were given")
        finally:
            proc.terminate()
            deadline = time.monotonic() + 10.0
            while proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
            if proc.poll() is None:
                proc.kill()
            proc.communicate()


if __name__ == "__main__":
    rostest.rosrun("quad_il", "sim_missing_param", MissingParamTest)
