"""Disk full while a shard is written (issue 30, fault table in docs/CONVENTIONS.md).

RLIMIT_FSIZE, set in the writing child only, stands in for a full disk: a write past the limit writes what
fits and then fails with EFBIG (SIGXFSZ ignored, as it would otherwise kill the writer). Required: a clear
error naming the file, the complete data valid, the torn part never taken for complete. The C++ writer's own
gtest (DatasetWriter.DiskFull*) covers a failure after completed shards; here the real tool with the Python
and C++ readers, and the Python collector's writer (quad_il.data.writer through quad_il.imitation.dataset).
"""

from __future__ import annotations

import resource
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

from test_collector_crash import SEED, H, W, assert_matches_a_clean_run

from quad_il.data import load_dataset, open_dataset
from quad_il.data.format import HEADER_SIZE
from quad_il.data.synthetic import find_collector_tool
from quad_il.imitation.dataset import read_records

HERE = Path(__file__).resolve().parent


def file_size_limit(limit_bytes: int) -> Callable[[], None]:
    """preexec_fn of a child whose files cannot grow past limit_bytes (EFBIG instead of SIGXFSZ)."""

    def setup() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # an ignored disposition survives exec
        _, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, hard))

    return setup


def record_size(tmp_path: Path) -> int:
    """The record size of W x H synthetic records, from a one-record dataset."""
    probe = tmp_path / "probe"
    subprocess.run(
        [str(find_collector_tool("write_synthetic_dataset")), "--out", str(probe), "--seed", "1", "--records",
         "1", "--width", str(W), "--height", str(H), "--no-fsync"],
        check=True, capture_output=True,
    )  # fmt: skip
    return open_dataset(probe).header.record_size


def test_cpp_writer_disk_full_names_the_shard_and_readers_keep_only_whole_records(tmp_path: Path) -> None:
    rs = record_size(tmp_path)
    limit = HEADER_SIZE + 3 * rs + rs // 2  # the disk fills half-way through the fourth record
    out = tmp_path / "ds"
    proc = subprocess.run(
        [str(find_collector_tool("write_synthetic_dataset")), "--out", str(out), "--seed", str(SEED),
         "--records", "20", "--width", str(W), "--height", str(H), "--shard-size-mb", "1", "--no-fsync"],
        capture_output=True, text=True, timeout=60, preexec_fn=file_size_limit(limit),
    )  # fmt: skip
    partial = out / "shard_000000.qdr.partial"
    error = f"cannot write {partial}: File too large"
    assert proc.returncode == 1, proc.stderr
    assert f"write_synthetic_dataset: writer error: {error}" in proc.stderr
    # The torn shard keeps its .partial name; the manifest (written within the limit) says why.
    assert not (out / "shard_000000.qdr").exists()
    assert partial.stat().st_size == limit
    ds = open_dataset(out)
    assert ds.status == "incomplete"
    assert ds.manifest["shards"] == []  # never listed as complete
    assert ds.manifest["writer_error"] == error
    assert [(s.name, s.partial, s.num_records, s.torn_tail_bytes) for s in ds.shards] == [
        (partial.name, True, 3, rs // 2)
    ]
    report = ds.verify()
    assert report.errors == []
    assert report.warnings == [
        f"dataset is incomplete: the writer failed: {error}",
        f"{partial.name}: torn tail of {rs // 2} bytes after record 3 (skipped)",
    ]
    # The three whole records are exactly those of a clean run; the torn one is skipped (Python and C++).
    assert len(load_dataset(out)) == 3
    assert_matches_a_clean_run(out, 3, tmp_path)
    verify = subprocess.run(
        [str(find_collector_tool("read_dataset")), "verify", str(out)], capture_output=True, text=True
    )
    assert verify.returncode == 3, verify.stdout  # warnings only
    assert f"WARNING dataset is incomplete: the writer failed: {error}" in verify.stdout


EPISODE_WRITER = """
import sys
sys.path.insert(0, sys.argv[2])
from test_imitation_dataset import make_records
from quad_il.imitation.dataset import EpisodeWriter
from quad_il.imitation.types import ImitationError
w = EpisodeWriter(sys.argv[1], {"round_index": "0"}, fsync=False)
w.write(1, make_records(3))
try:
    w.write(2, make_records(400))
except ImitationError as e:
    print(e)
    w.finalize()
    sys.exit(3)
"""


def test_collector_writer_disk_full_names_the_file_and_keeps_earlier_episodes(tmp_path: Path) -> None:
    out = tmp_path / "data"
    proc = subprocess.run(
        [sys.executable, "-c", EPISODE_WRITER, str(out), str(HERE)],
        capture_output=True,
        text=True,
        timeout=60,
        preexec_fn=file_size_limit(64 * 1024),
    )
    assert proc.returncode == 3, proc.stdout + proc.stderr
    partial = out / "shard_000000.qdr.partial"
    assert proc.stdout.strip() == f"dataset writer failed: cannot write {partial}: File too large"
    # The manifest says why; the three records of the first episode stay readable, the torn one is skipped.
    ds = open_dataset(out)
    assert (
        ds.status == "incomplete" and ds.manifest["writer_error"] == f"cannot write {partial}: File too large"
    )
    assert ds.verify().errors == [] and ds.shards[0].torn_tail_bytes > 0
    records = read_records(out)
    assert len(records) >= 3 and partial.stat().st_size == 64 * 1024
    assert [r.obs.stamp_s for r in records[:3]] == [12.0, 12.1, 12.2]
