"""Shared by the interactive-round rostest checks (il_dagger_round_check.py, il_mega_round_check.py): wait for
the collector's manifest, and check that the round's dataset (shards + manifest, the one demonstration
format) is complete, verifies, and converts to the trainer's npz contract. (rostest runs a check script with
its own directory first on sys.path.)"""

from __future__ import annotations

import json
import time
import unittest
from pathlib import Path
from typing import Any

import numpy as np
import rospy

from quad_il.data import open_dataset
from quad_il.imitation.convert import select_records, shard_records_to_npz_arrays
from quad_il.imitation.dataset import episodes, read_records
from quad_il.imitation.types import Record


def wait_for_manifest(
    test: unittest.TestCase, data: Path, episodes: int, timeout_s: float = 140.0
) -> dict[str, Any]:
    """The collector's manifest (written after its episodes), checked for a finished round."""
    manifest = data / "collector_manifest.json"
    deadline = time.monotonic() + timeout_s
    while not manifest.is_file() and time.monotonic() < deadline and not rospy.is_shutdown():
        time.sleep(0.2)
    test.assertTrue(manifest.is_file(), f"no {manifest}: the collector did not finish its episodes")
    m = json.loads(manifest.read_text())
    test.assertFalse(m["interrupted"])
    test.assertEqual(m["episodes"], episodes)
    return m


def episode_records(test: unittest.TestCase, data: Path) -> list[list[Record]]:
    """The records of each episode, once the dataset is finalised and verifies without error."""
    ds = open_dataset(data)
    test.assertEqual(ds.status, "complete")
    report = ds.verify()
    test.assertTrue(report.ok and not report.warnings, report.format())
    groups = episodes(read_records(data))
    test.assertGreaterEqual(len(groups), 1)
    return groups


def check_converts(test: unittest.TestCase, data: Path, n_records: int) -> None:
    records, rounds, _ = select_records([data])
    arrays = shard_records_to_npz_arrays(records, rounds)
    test.assertEqual(len(arrays), n_records)
    test.assertTrue(np.isfinite(arrays.bspline_ctrl_world).all())
