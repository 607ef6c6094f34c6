"""Checks on collected datasets: run-to-run reproducibility and depth/odometry synchronisation.

Used by the collection tests (tests/rostest/collect_*.py) and the collection benchmark. As a command, it
prints each dataset's record count and the sha256 of its records without the wall-clock fields, and with two
datasets the fields that differ (exit 1 if any, 2 if a dataset cannot be read):

    python -m quad_il.collection.compare DATASET_A [DATASET_B]
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from quad_il.data.format import DatasetError
from quad_il.data.shards import open_dataset
from quad_il.tools.cli import HelpFormatter

# Record fields that hold wall-clock (CPU) measurements, and the CRC that covers them: they differ between two
# otherwise identical runs.
TIMING_FIELDS = ("t_map_update_ms", "t_frontend_ms", "t_optimization_ms", "t_total_ms")
NON_REPRODUCIBLE_FIELDS = (*TIMING_FIELDS, "crc32")


def dataset_records(path: str | os.PathLike) -> np.ndarray:
    """Every valid record of a dataset, in shard order, as one structured array (a copy)."""
    ds = open_dataset(path)
    report = ds.verify()
    if not report.ok:
        raise ValueError(f"{path}: dataset has errors:\n{report.format()}")
    parts = [np.array(s.records) for s in ds.shards]
    if not parts:
        return np.zeros(0)
    return np.concatenate(parts)


@dataclass
class Difference:
    index: int
    field: str
    a: object
    b: object

    def __str__(self) -> str:
        return f"record {self.index} field {self.field}: {self.a!r} != {self.b!r}"


def compare_records(
    a: np.ndarray, b: np.ndarray, ignore: Iterable[str] = NON_REPRODUCIBLE_FIELDS, limit: int = 20
) -> list[str]:
    """Differences between two record arrays (all fields but `ignore`, bit-exact); [] when identical."""
    problems: list[str] = []
    if a.dtype != b.dtype:
        return [f"record layouts differ: {a.dtype} vs {b.dtype}"]
    if len(a) != len(b):
        problems.append(f"record counts differ: {len(a)} vs {len(b)}")
    n = min(len(a), len(b))
    skip = set(ignore)
    for name in a.dtype.names:
        if name in skip:
            continue
        if n == 0:
            continue
        # Bit-exact: compare the bytes (NaN == NaN, -0.0 != 0.0).
        x = np.ascontiguousarray(a[name][:n]).reshape(n, -1).view(np.uint8)
        y = np.ascontiguousarray(b[name][:n]).reshape(n, -1).view(np.uint8)
        if np.array_equal(x, y):
            continue
        rows = np.nonzero(np.any(x != y, axis=1))[0]
        for i in rows[: max(0, limit - len(problems))]:
            problems.append(str(Difference(int(i), name, _short(a[name][i]), _short(b[name][i]))))
        if len(problems) >= limit:
            break
    return problems


def _short(v: object) -> object:
    arr = np.asarray(v)
    if arr.size > 6:
        return f"{arr.dtype}{arr.shape} array"
    return arr.tolist()


def stamp_gaps_s(records: np.ndarray) -> np.ndarray:
    """|odom stamp - depth stamp| of every record, seconds."""
    if len(records) == 0:
        return np.zeros(0)
    return np.abs(records["odom_stamp_s"] - records["depth_stamp_s"])


def records_digest(records: np.ndarray, ignore: Iterable[str] = NON_REPRODUCIBLE_FIELDS) -> str:
    """sha256 of every record field but `ignore`, field by field in layout order: equal digests mean
    bit-identical records apart from the wall-clock timings (two runs of one binary differ in those)."""
    h = hashlib.sha256()
    skip = set(ignore)
    for name in records.dtype.names or ():
        if name not in skip:
            h.update(name.encode())
            h.update(np.ascontiguousarray(records[name]).tobytes())
    return h.hexdigest()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.collection.compare", formatter_class=HelpFormatter, description=__doc__
    )
    ap.add_argument("datasets", nargs="+", help="one or two dataset directories (shards + manifest)")
    args = ap.parse_args(argv)
    if len(args.datasets) > 2:
        ap.error("give one or two dataset directories")
    try:
        records = [dataset_records(d) for d in args.datasets]
    except (OSError, ValueError, DatasetError) as e:
        print(f"compare: {e}", file=sys.stderr)
        return 2
    for d, r in zip(args.datasets, records, strict=True):
        print(f"{d}: {len(r)} records, sha256 without timing fields {records_digest(r)}")
    if len(records) == 2:
        diffs = compare_records(*records)
        print("differences: " + ("none" if not diffs else "\n  " + "\n  ".join(diffs)))
        return 1 if diffs else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
