#!/usr/bin/env python3
"""rostest node: SIGKILL of the collecting planner in the middle of a collect.launch run.

Starts collect.launch (1 episode of tests/rostest/collect_test.yaml) on its own master, waits until the
planner has written at least MIN_RECORDS records, kills fast_planner_node with SIGKILL (no finalisation), and
checks that every record completed before the kill is readable and CRC-valid by the Python and C++ readers,
that the dataset is reported incomplete (not corrupt), and that `read_dataset recover` turns it into a clean
dataset.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import tempfile
import time
import unittest
import xmlrpc.client
from pathlib import Path

import rostest

from quad_il.collection.launch_run import start_collect, stop
from quad_il.data.shards import open_dataset
from quad_il.data.synthetic import find_collector_tool

HERE = Path(__file__).resolve().parent
MIN_RECORDS = 3
RECORD_SIZE = 158080  # 320x240, max_ctrl_pts 128, no yaw points (config/collector.yaml)
HEADER = 4096


def records_on_disk(d: Path) -> int:
    return sum(max(0, p.stat().st_size - HEADER) // RECORD_SIZE for p in d.glob("shard_*"))


class CollectCrashTest(unittest.TestCase):
    def test_sigkill_planner(self) -> None:
        tmp = Path(tempfile.mkdtemp(prefix="collect_crash_"))
        out = tmp / "ds"
        try:
            proc, port = start_collect(
                out,
                tmp / "run.log",
                collect_config=HERE / "collect_test.yaml",
                seeds="4",
                episodes=1,
                output="log",
            )
            try:
                deadline = time.monotonic() + 60.0
                while records_on_disk(out) < MIN_RECORDS:
                    self.assertIsNone(proc.poll(), (tmp / "run.log").read_text()[-3000:])
                    self.assertLess(time.monotonic(), deadline, "no records written in 60 s")
                    time.sleep(0.05)
                master = xmlrpc.client.ServerProxy(f"http://localhost:{port}")
                code, _, uri = master.lookupNode("/test", "/fast_planner")
                self.assertEqual(code, 1)
                _, _, pid = xmlrpc.client.ServerProxy(uri).getPid("/test")
                os.kill(int(pid), signal.SIGKILL)
                killed_at = records_on_disk(out)
            finally:
                stop(proc)
            self.assertGreaterEqual(killed_at, MIN_RECORDS)
            self.assertIn("status: incomplete", (out / "manifest.yaml").read_text())
            self.assertEqual(len(list(out.glob("*.partial"))), 1)
            ds = open_dataset(out)
            report = ds.verify()
            self.assertTrue(report.ok, report.format())  # warnings only: incomplete, maybe a torn tail
            n = len(ds)
            self.assertGreaterEqual(n, killed_at)
            for i in range(n):
                rec = ds[i]
                self.assertEqual(int(rec["seq"]), i)
            tool = find_collector_tool("read_dataset")
            verify = subprocess.run([str(tool), "verify", str(out)], capture_output=True, text=True)
            self.assertIn(verify.returncode, (0, 3), verify.stdout + verify.stderr)
            rec = subprocess.run([str(tool), "recover", str(out)], capture_output=True, text=True)
            self.assertEqual(rec.returncode, 0, rec.stdout + rec.stderr)
            self.assertIn("status: recovered", (out / "manifest.yaml").read_text())
            self.assertEqual(list(out.glob("*.partial")), [])
            ds2 = open_dataset(out)
            self.assertTrue(ds2.verify().ok)
            self.assertEqual(len(ds2), n)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    rostest.rosrun("quad_il", "collect_crash", CollectCrashTest)
