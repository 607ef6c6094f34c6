"""Crash safety: a writer killed with SIGKILL leaves every completed record readable; torn tails and flipped
bytes are reported with shard and record index; SIGINT finalises the dataset."""

from __future__ import annotations

import logging
import shutil
import signal
import subprocess
from pathlib import Path

import numpy as np
import pytest

from quad_il.data import CorruptDataError, load_dataset, open_dataset
from quad_il.data.format import HEADER_SIZE
from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset

W, H = 64, 48
SEED = 11
SHARD_MB = 0.2  # about 17 records of 64x48 per shard


def start_writer(args: list[str]) -> subprocess.Popen[str]:
    tool = find_collector_tool("write_synthetic_dataset")
    return subprocess.Popen([str(tool), *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def signal_when(proc: subprocess.Popen[str], prefix: str, written: int, sig: int) -> tuple[int, str, str]:
    """Reads the writer's stdout until a line starting with `prefix` reports at least `written` records on
    disk, sends `sig`, and returns (exit status, rest of stdout, stderr). Waits on the child's output."""
    assert proc.stdout is not None
    try:
        for line in proc.stdout:
            if line.startswith(prefix):
                fields = dict(kv.split("=") for kv in line.split()[1:])
                if int(fields["written"]) >= written:
                    break
        else:
            pytest.fail(
                f"writer exited before writing {written} records: {proc.stderr.read() if proc.stderr else ''}"
            )
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    return proc.returncode, out, err


def writer_args(out: Path, *extra: str) -> list[str]:
    return ["--out", str(out), "--seed", str(SEED), "--until-signal", "--width", str(W), "--height", str(H),
            "--shard-size-mb", str(SHARD_MB), "--no-fsync", *extra]  # fmt: skip


@pytest.fixture(scope="module")
def killed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A writer killed with SIGKILL after exactly 60 records reached the disk (3 completed shards of 16
    records and a partial one with 12): a planner process that crashed without finalising."""
    out = tmp_path_factory.mktemp("crash") / "killed"
    rc, _, _ = signal_when(
        start_writer(writer_args(out, "--pause-after", "60")), "paused", 60, signal.SIGKILL
    )
    assert rc == -signal.SIGKILL
    return out


@pytest.fixture()
def killed_copy(killed: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(killed, tmp_path / "killed"))


def cpp_verify(path: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(find_collector_tool("read_dataset")), "verify", str(path)],
        capture_output=True,
        text=True,
        check=False,
    )


def assert_matches_a_clean_run(crashed: Path, n: int, tmp_path: Path) -> None:
    clean = write_synthetic_dataset(
        tmp_path / "clean", seed=SEED, records=n, width=W, height=H, shard_size_mb=SHARD_MB
    )
    assert load_dataset(crashed).records.tobytes() == load_dataset(clean).records.tobytes()


def test_sigkill_leaves_every_completed_record_readable_and_identical(killed: Path, tmp_path: Path) -> None:
    ds = open_dataset(killed)
    assert ds.status == "incomplete"
    assert [s.name for s in ds.shards] == [
        "shard_000000.qdr", "shard_000001.qdr", "shard_000002.qdr", "shard_000003.qdr.partial"
    ]  # fmt: skip
    assert [s.num_records for s in ds.shards] == [16, 16, 16, 12]
    report = ds.verify()
    assert report.errors == []
    assert report.warnings == [
        "dataset is incomplete: the writer did not finalise it (killed or still running)"
    ]
    assert report.valid_records == len(ds) == 60
    assert_matches_a_clean_run(killed, 60, tmp_path)
    # The manifest rewritten at each completed shard lists them, with the config and seeds.
    assert [s["file"] for s in ds.manifest["shards"]] == [s.name for s in ds.shards[:-1]]
    assert ds.manifest["world_seeds"] and ds.manifest["config"]["image_width"] == W
    rc = cpp_verify(killed)
    assert rc.returncode == 3, rc.stdout  # warnings only
    assert "WARNING dataset is incomplete" in rc.stdout


def test_sigkill_at_a_random_moment_mid_stream_loses_no_completed_record(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    proc = start_writer(writer_args(out, "--progress-every", "5", "--rate-hz", "400"))
    rc, _, _ = signal_when(proc, "progress", 40, signal.SIGKILL)
    assert rc == -signal.SIGKILL
    ds = open_dataset(out)
    report = ds.verify()
    assert report.errors == []
    assert all(not s.partial for s in ds.shards[:-1])
    assert len(ds) >= 40
    assert_matches_a_clean_run(out, len(ds), tmp_path)


def test_torn_tail_is_reported_with_shard_and_skipped(
    killed_copy: Path, caplog: pytest.LogCaptureFixture
) -> None:
    partial = sorted(killed_copy.glob("*.partial"))[0]
    ds = open_dataset(killed_copy)
    complete = ds.shards[-1].num_records
    rs = ds.header.record_size
    # A writer killed inside write(2) leaves the start of a record: append 1000 bytes of one.
    with open(partial, "ab") as f:
        f.write(partial.read_bytes()[HEADER_SIZE : HEADER_SIZE + 1000])
    ds = open_dataset(killed_copy)
    assert ds.shards[-1].num_records == complete and ds.shards[-1].torn_tail_bytes == 1000
    expected = f"{partial.name}: torn tail of 1000 bytes after record {complete} (skipped)"
    assert expected in ds.verify().warnings
    assert f"WARNING {expected}" in cpp_verify(killed_copy).stdout
    with caplog.at_level(logging.WARNING, logger="quad_il.data.shards"):
        loaded = load_dataset(killed_copy)
    assert len(loaded) == len(ds)
    assert f"{partial.name}: torn tail of 1000 bytes after record {complete}" in caplog.text
    assert rs > 1000


def test_recover_cuts_the_torn_tail_and_finalises(killed_copy: Path) -> None:
    partial = sorted(killed_copy.glob("*.partial"))[0]
    with open(partial, "ab") as f:
        f.write(b"\x07" * 333)
    before = load_dataset(killed_copy).records
    tool = find_collector_tool("read_dataset")
    out = subprocess.run(
        [str(tool), "recover", str(killed_copy)], capture_output=True, text=True, check=True
    ).stdout
    assert "cut 333 bytes" in out and "renamed to" in out
    ds = open_dataset(killed_copy)
    assert ds.status == "recovered"
    report = ds.verify()
    assert report.errors == [] and report.warnings == []
    assert not list(killed_copy.glob("*.partial"))
    assert load_dataset(killed_copy).records.tobytes() == before.tobytes()
    assert sum(e["records"] for e in ds.manifest["episodes"]) == len(ds)


def test_flipped_byte_is_detected_by_crc_with_shard_and_record(tmp_path: Path) -> None:
    path = write_synthetic_dataset(
        tmp_path / "ds", seed=2, records=40, width=W, height=H, shard_size_mb=SHARD_MB
    )
    shard = path / "shard_000001.qdr"
    data = bytearray(shard.read_bytes())
    rs = open_dataset(path).header.record_size
    data[HEADER_SIZE + 2 * rs + rs // 2] ^= 0x04  # record 2 of shard 1, inside its depth image
    shard.write_bytes(bytes(data))

    report = open_dataset(path).verify()
    assert len(report.errors) == 1
    assert report.errors[0].startswith("shard_000001.qdr record 2: CRC mismatch (stored ")
    assert report.valid_records == 39
    rc = cpp_verify(path)
    assert rc.returncode == 1
    assert "ERROR shard_000001.qdr record 2: CRC mismatch" in rc.stdout
    with pytest.raises(CorruptDataError, match=r"shard_000001\.qdr record 2: CRC mismatch"):
        load_dataset(path)
    skipped = load_dataset(path, on_corrupt="skip")
    assert len(skipped) == 39
    assert open_dataset(path).shards[1].records["seq"][2] not in skipped["seq"]


def test_truncated_completed_shard_is_corruption(tmp_path: Path) -> None:
    path = write_synthetic_dataset(
        tmp_path / "ds", seed=2, records=40, width=W, height=H, shard_size_mb=SHARD_MB
    )
    shard = path / "shard_000000.qdr"
    shard.write_bytes(shard.read_bytes()[:-10])
    with pytest.raises(CorruptDataError, match=r"shard_000000\.qdr: torn tail of .* in a completed shard"):
        load_dataset(path)
    errors = open_dataset(path).verify().errors
    assert any("shard_000000.qdr: holds" in e and "the manifest says" in e for e in errors)


def test_sigint_finalises_the_dataset(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    rc, stdout, stderr = signal_when(
        start_writer(writer_args(out, "--progress-every", "5", "--rate-hz", "400")),
        "progress",
        25,
        signal.SIGINT,
    )
    assert rc == 0, stderr
    assert "interrupted by signal 2; dataset finalised" in stderr
    assert "done submitted=" in stdout
    ds = open_dataset(out)
    assert ds.status == "complete"
    assert not list(out.glob("*.partial"))
    report = ds.verify()
    assert report.errors == [] and report.warnings == []
    m = ds.manifest
    assert m["counts"]["written"] == m["counts"]["submitted"] == len(ds) >= 25
    np.testing.assert_array_equal(load_dataset(out)["seq"], np.arange(len(ds)))


def test_sigint_while_paused_still_finalises(tmp_path: Path) -> None:
    out = tmp_path / "ds"
    rc, _, stderr = signal_when(
        start_writer(writer_args(out, "--pause-after", "20")), "paused", 20, signal.SIGINT
    )
    assert rc == 0, stderr
    ds = open_dataset(out)
    assert ds.status == "complete" and len(ds) == 20
    assert [s.name for s in ds.shards] == ["shard_000000.qdr", "shard_000001.qdr"]
