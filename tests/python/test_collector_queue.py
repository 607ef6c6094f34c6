"""Full-queue policy through the real writer process: drops are counted and listed, never silent.

The deterministic version (a stalled writer thread, exact drop counts) is the gtest
DatasetWriter.DropPolicyCountsEveryDropAndLeavesSeqGaps; here the writer is simply overloaded (queue of one
slot, 320x240 records submitted back to back with a reused image), and the accounting must be exact whatever
the scheduler did.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from quad_il.data import load_dataset, open_dataset
from quad_il.data.synthetic import write_synthetic_dataset


def test_drop_policy_counts_every_drop_and_the_gaps_match(tmp_path: Path) -> None:
    out = write_synthetic_dataset(
        tmp_path / "ds",
        seed=4,
        records=300,
        width=320,
        height=240,
        queue_capacity=1,
        policy="drop",
        shard_size_mb=8.0,
        extra_args=["--distinct-images", "1", "--max-ctrl-pts", "40", "--max-yaw-pts", "40"],
    )
    m = open_dataset(out).manifest
    counts = m["counts"]
    assert counts["submitted"] == 300
    assert counts["written"] + counts["dropped"] == 300
    assert counts["dropped"] > 0  # one slot cannot absorb back-to-back 150 kB records
    seqs = load_dataset(out)["seq"]
    assert len(seqs) == counts["written"]
    missing = sorted(set(range(300)) - set(seqs.tolist()))
    assert missing == m["dropped_seqs"]
    assert np.all(np.diff(seqs.astype(np.int64)) > 0)
    assert m["config"]["full_queue_policy"] == "drop"


def test_block_policy_loses_nothing_under_the_same_load(tmp_path: Path) -> None:
    out = write_synthetic_dataset(
        tmp_path / "ds",
        seed=4,
        records=100,
        width=320,
        height=240,
        queue_capacity=1,
        policy="block",
        extra_args=["--distinct-images", "1", "--max-ctrl-pts", "40", "--max-yaw-pts", "40"],
    )
    m = open_dataset(out).manifest
    assert m["counts"]["written"] == 100 and m["counts"]["dropped"] == 0 and m["dropped_seqs"] == []
    np.testing.assert_array_equal(load_dataset(out)["seq"], np.arange(100))
