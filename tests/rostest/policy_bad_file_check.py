#!/usr/bin/env python3
"""rostest node of policy_bad_file_cpp.test / policy_bad_file_py.test (issue 30, fault table: a truncated or
foreign policy.ts). Starts the policy node of ~controller (cpp: quad_policy's policy_node; py: quad_il's
policy_node.py) with rosrun on this test's master, once per bad policy file, and requires each start to end
with a non-zero exit status and a fatal message that names the file and what is wrong with it:

- a truncated copy of a real export (the goal-line test policy cut in half);
- a text file named policy.ts;
- a zip archive of something else;
- a TorchScript module that is not a quad_il policy (no metadata);
- a TorchScript module carrying a real policy's metadata but none of a policy's attributes;
- a TorchScript module with the metadata and the attributes but neither forward_net nor forward_prepared.

A real export of the same policy must start (the same command stays up until stopped), so the test fails if
the node refused every file."""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
import time
import unittest
import zipfile
from pathlib import Path

import rospy
import rostest
import torch

from quad_il.inference.random_policy import export_goal_line_policy
from quad_il.learning.export import META_FILE

NODES = {"cpp": ("quad_policy", "policy_node"), "py": ("quad_il", "policy_node.py")}
EXIT_GUARD_S = 120.0  # wall time a refused start may take (a failure guard: starts take seconds)


class Linear(torch.nn.Module):
    """A TorchScript module that is no policy."""

    def __init__(self) -> None:
        super().__init__()
        self.fc = torch.nn.Linear(3, 2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc(x)


class AttributesOnly(torch.nn.Module):
    """A module with a policy's attributes (from the metadata) and only a plain forward."""

    def __init__(self, meta: dict) -> None:
        super().__init__()
        self.input_height = int(meta["preprocessing"]["input_height"])
        self.input_width = int(meta["preprocessing"]["input_width"])
        self.max_depth_m = float(meta["preprocessing"]["max_depth_m"])
        self.num_ctrl_pts = int(meta["output"]["num_ctrl_pts"])
        self.horizon_s = float(meta["output"]["horizon_s"])

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.max_depth_m


def bad_files(work: Path) -> list[tuple[str, Path, str]]:
    """(case, file, expected part of the message) of every bad policy file, and the real export first."""
    real = export_goal_line_policy(work / "real" / "policy.ts")
    extra = {META_FILE: ""}
    torch.jit.load(str(real), _extra_files=extra)
    meta_json = extra[META_FILE]
    meta = json.loads(meta_json)
    files = []

    truncated = work / "truncated" / "policy.ts"
    truncated.parent.mkdir()
    data = real.read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    files.append(("truncated export", truncated, "cannot load the TorchScript policy"))

    text = work / "text" / "policy.ts"
    text.parent.mkdir()
    text.write_text("this is a text file, not a policy\n")
    files.append(("text file", text, "cannot load the TorchScript policy"))

    other_zip = work / "zip" / "policy.ts"
    other_zip.parent.mkdir()
    with zipfile.ZipFile(other_zip, "w") as z:
        z.writestr("notes/readme.txt", "a zip archive of something else\n")
        z.writestr("notes/data.csv", "a,b\n1,2\n")
    files.append(("zip of something else", other_zip, "cannot load the TorchScript policy"))

    plain = work / "plain" / "policy.ts"
    plain.parent.mkdir()
    torch.jit.save(torch.jit.script(Linear()), str(plain))
    files.append(("TorchScript module without metadata", plain, "not a quad_il policy export"))

    meta_only = work / "meta_only" / "policy.ts"
    meta_only.parent.mkdir()
    torch.jit.save(torch.jit.script(Linear()), str(meta_only), _extra_files={META_FILE: meta_json})
    files.append(("metadata without the policy's attributes", meta_only, "missing policy attribute"))

    no_methods = work / "no_methods" / "policy.ts"
    no_methods.parent.mkdir()
    torch.jit.save(
        torch.jit.script(AttributesOnly(meta)), str(no_methods), _extra_files={META_FILE: meta_json}
    )
    files.append(("attributes without the methods", no_methods, "neither forward_net nor forward_prepared"))
    return [("real export", real, ""), *files]


class PolicyBadFile(unittest.TestCase):
    def test_bad_policy_files_stop_the_node_at_start_naming_the_file(self) -> None:
        controller = rospy.get_param("~controller")
        pkg, node_type = NODES[controller]
        config = rospy.get_param("~policy_config")
        work = Path(tempfile.mkdtemp(prefix="policy_bad_file_"))
        self.addCleanup(shutil.rmtree, work, True)
        cases = bad_files(work)
        rospy.loginfo(f"policy_bad_file ({controller}): {len(cases)} policy files written in {work}")

        def command(i: int, path: Path) -> list[str]:
            return [
                "rosrun",
                pkg,
                node_type,
                f"__name:=policy_node_{i}",
                f"__ns:=/case_{i}",
                f"_config:={config}",
                f"_policy_file:={path}",
                "_send_to_tracker:=false",
            ]

        # The bad files' starts run side by side (each node is on its own; a start mostly loads torch).
        procs = {
            i: subprocess.Popen(command(i, path), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            for i, (_, path, expected) in enumerate(cases)
            if expected
        }
        try:
            for i, (case, path, expected) in enumerate(cases):
                with self.subTest(case=case):
                    if not expected:
                        self._starts(command(i, path), f"/case_{i}/policy/decision")
                        continue
                    stdout, stderr = procs[i].communicate(timeout=EXIT_GUARD_S)
                    output = stdout + stderr
                    rospy.loginfo(
                        f"policy_bad_file ({controller}) {case}: exit {procs[i].returncode}: {output.strip()}"
                    )
                    self.assertNotEqual(procs[i].returncode, 0, f"{case}: the node exited 0\n{output}")
                    fatal = [line for line in output.splitlines() if "FATAL" in line]
                    self.assertTrue(fatal, f"{case}: no fatal message\n{output}")
                    self.assertIn(str(path), fatal[-1], f"{case}: the message does not name the file")
                    self.assertIn(expected, fatal[-1], f"{case}: the message does not say what is wrong")
        finally:
            for p in procs.values():
                if p.poll() is None:
                    p.kill()
                    p.wait()

    def _starts(self, cmd: list[str], decision_topic: str) -> None:
        """The real export: the node comes up (advertises its decisions) and stays up until stopped."""
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        try:
            deadline = time.monotonic() + EXIT_GUARD_S
            while not any(t == decision_topic for t, _ in rospy.get_published_topics()):
                if proc.poll() is not None:
                    self.fail(f"the node exited with the real export: {proc.stdout.read()}")
                self.assertLess(time.monotonic(), deadline, "the node did not come up with the real export")
                time.sleep(0.1)
            self.assertIsNone(proc.poll(), "the node exited with the real export")
        finally:
            proc.terminate()
            proc.wait(timeout=30.0)


if __name__ == "__main__":
    rospy.init_node("policy_bad_file_check")
    rostest.rosrun("quad_il", "policy_bad_file_check", PolicyBadFile)
