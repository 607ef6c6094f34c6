"""The Python twin of the C++ dataset writer (quad_il.data.writer): the same bytes, the same manifest, the
same rejections, and each side reads the other's datasets (docs/data_format.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from quad_il.data import open_dataset
from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset
from quad_il.data.writer import DatasetWriter, PlanRecordData, WriterConfig, WriterError, utf8_prefix

W, H = 16, 12


def config(out: Path, **changes: object) -> WriterConfig:
    """The configuration write_synthetic_dataset uses at W x H (its camera: 90 degrees horizontal)."""
    values: dict[str, object] = {
        "output_dir": str(out),
        "shard_size_mb": 0.02,
        "queue_capacity": 32,
        "full_queue_policy": "block",
        "image_width": W,
        "image_height": H,
        "max_ctrl_pts": 128,
        "max_yaw_pts": 128,
        "fsync": False,
        "software_commit": "unknown",
        "camera_fx_px": 9.68,
        "camera_fy_px": 9.68,
        "camera_cx_px": 8.0,
        "camera_cy_px": 6.0,
    }
    values.update(changes)
    return WriterConfig(**values)  # type: ignore[arg-type]


def manifest_without_times(path: Path) -> list[str]:
    return [
        line
        for line in path.read_text().splitlines()
        if not line.startswith(("created_utc:", "finalized_utc:", "  output_dir:"))
    ]


def test_the_same_records_give_byte_identical_shards_and_the_same_manifest(tmp_path: Path) -> None:
    cpp = write_synthetic_dataset(
        tmp_path / "cpp", seed=3, records=9, width=W, height=H, shard_size_mb=0.02, records_per_episode=4
    )
    ds = open_dataset(cpp)
    assert len(ds.shards) >= 3  # rotation is exercised (0.02 MB: a few records per shard)
    w = DatasetWriter(config(tmp_path / "py"))
    for key, value in ds.manifest["run_info"].items():
        w.set_run_info(key, value)
    for shard in ds.shards:
        for rec in shard.records:
            assert w.record(PlanRecordData.from_stored(rec))[0] == "queued"
    assert w.finalize()
    cpp_files = sorted(p.name for p in cpp.iterdir())
    assert sorted(p.name for p in (tmp_path / "py").iterdir()) == cpp_files
    for name in cpp_files:
        if name.endswith(".qdr"):
            assert (tmp_path / "py" / name).read_bytes() == (cpp / name).read_bytes(), name
    assert manifest_without_times(tmp_path / "py" / "manifest.yaml") == manifest_without_times(
        cpp / "manifest.yaml"
    )


def sample(i: int, **changes: object) -> PlanRecordData:
    t = 1.0 + 0.1 * i
    knots = np.arange(-3, 9, dtype=np.float64) * 0.25 + t
    ctrl = np.column_stack([np.linspace(0, 3, 8) + i, np.zeros(8), np.full(8, 1.5)])
    depth = np.full((H, W), 2.5, dtype=np.float32)
    depth[0, 0], depth[0, 1], depth[0, 2] = np.nan, np.inf, -np.inf
    values: dict[str, object] = {
        "episode_id": i // 2,
        "world_seed": 100 + i // 2,
        "sim_time_s": t,
        "depth_m": depth,
        "depth_stamp_s": t,
        "odom_stamp_s": t - 0.005,
        "p_world_body": [i, 0.0, 1.5],
        "v_world": [1.0, 0.0, 0.0],
        "q_world_body": [0.0, 0.0, 0.0, 1.0],
        "w_body": [0.0, 0.0, 0.0],
        "goal_world": [20.0, 0.0, 1.5],
        "order": 3,
        "traj_id": i,
        "start_time_s": t,
        "knots": knots,
        "ctrl_pts_world": ctrl,
        "status_code": 2,
        "status_text": f"demo é {i}",
        "timings_ms": (0.5, 1.0, 2.0, 3.5),
        "flags": 0,
    }
    values.update(changes)
    return PlanRecordData(**values)  # type: ignore[arg-type]


def test_the_cpp_reader_verifies_and_dumps_what_the_python_writer_wrote(tmp_path: Path) -> None:
    w = DatasetWriter(config(tmp_path / "py"))
    w.set_run_info("writer", "test")
    for i in range(5):
        assert w.record(sample(i)) == ("queued", i)
    assert w.finalize()
    tool = str(find_collector_tool("read_dataset"))
    verify = subprocess.run([tool, "verify", str(tmp_path / "py")], capture_output=True, text=True)
    assert verify.returncode == 0, verify.stdout + verify.stderr
    dump = subprocess.run(
        [tool, "dump", str(tmp_path / "py"), "--format", "jsonl", "--depth", "full"],
        capture_output=True,
        text=True,
        check=True,
    )
    rows = [json.loads(line) for line in dump.stdout.splitlines() if line.startswith("{")]
    assert len(rows) == 5
    for i, row in enumerate(rows):
        s = sample(i)
        assert row["seq"] == i and row["episode_id"] == s.episode_id and row["world_seed"] == s.world_seed
        assert row["odom_stamp_s"] == s.odom_stamp_s and row["plan_status_code"] == 2
        # the dump writes the text byte-wise (\u00XX for bytes >= 0x80): back to bytes, then UTF-8
        assert row["plan_status_text"].encode("latin-1").decode("utf-8") == f"demo é {i}"
        np.testing.assert_array_equal(row["knots"], s.knots)
        np.testing.assert_array_equal(np.reshape(row["ctrl_pts_world"], (-1, 3)), s.ctrl_pts_world)
    m = yaml.safe_load((tmp_path / "py" / "manifest.yaml").read_text())
    assert m["status"] == "complete" and m["counts"]["written"] == 5 and m["run_info"] == {"writer": "test"}
    assert [e["records"] for e in m["episodes"]] == [2, 2, 1] and m["world_seeds"] == [100, 101, 102]


def test_the_python_reader_reads_the_python_writers_records_exactly(tmp_path: Path) -> None:
    w = DatasetWriter(config(tmp_path / "py", shard_size_mb=0.001))  # below one record: one per shard
    for i in range(3):
        w.record(sample(i))
    w.finalize()
    ds = open_dataset(tmp_path / "py")
    assert ds.verify().ok and len(ds.shards) == 3 and len(ds) == 3
    rec = ds[1]
    depth = ds.shards[1].depth_m(0)
    assert np.isnan(depth[0, 0]) and depth[0, 1] == np.inf and depth[0, 2] == -np.inf and depth[5, 5] == 2.5
    assert bytes(rec["plan_status_text"]).rstrip(b"\0").decode() == "demo é 1"
    assert rec["t_total_ms"] == 3.5 and rec["num_ctrl_pts"] == 8 and rec["num_knots"] == 12


def test_given_seqs_are_kept_with_their_gaps_and_must_increase(tmp_path: Path) -> None:
    w = DatasetWriter(config(tmp_path / "py"))
    assert w.record(sample(0), seq=4) == ("queued", 4)
    assert w.record(sample(1)) == ("queued", 5)  # the default continues after the given one
    assert w.record(sample(2), seq=9) == ("queued", 9)
    with pytest.raises(WriterError, match="seq 9 is not after the previous record's 9"):
        w.record(sample(3), seq=9)
    w.finalize()
    ds = open_dataset(tmp_path / "py")
    assert ds.verify().ok and [int(ds[i]["seq"]) for i in range(len(ds))] == [4, 5, 9]


def test_invalid_records_are_rejected_with_the_cpp_writers_reasons(tmp_path: Path) -> None:
    # The C++ writer's own words for the same faults (write_synthetic_dataset with too small limits).
    tool = find_collector_tool("write_synthetic_dataset")
    out = subprocess.run(
        [
            str(tool),
            "--out",
            str(tmp_path / "cpp"),
            "--records",
            "4",
            "--width",
            str(W),
            "--height",
            str(H),
            "--max-ctrl-pts",
            "20",
            "--max-yaw-pts",
            "4",
            "--no-fsync",
        ],
        capture_output=True,
        text=True,
    )
    cpp_reasons = [line.split("rejected: ", 1)[1] for line in out.stderr.splitlines() if "rejected: " in line]
    ds_dir = write_synthetic_dataset(tmp_path / "ok", records=4, width=W, height=H)
    records = [r for s in open_dataset(ds_dir).shards for r in s.records]
    w = DatasetWriter(config(tmp_path / "py", max_ctrl_pts=20, max_yaw_pts=4))
    py_reasons = [w.record(PlanRecordData.from_stored(r))[1] for r in records]
    assert py_reasons == cpp_reasons and len(cpp_reasons) == 4
    bad = {
        "odom_stamp_s": (float("nan"), "odometry has a non-finite value"),
        "q_world_body": ([0.0, 0.0, 0.0, 2.0], "odometry quaternion has norm 2.000000, not 1"),
        "order": (9, "B-spline order 9 is outside [1, 7]"),
        "knots": (np.arange(11.0), "B-spline has 11 knots, expected control points + order + 1 = 12"),
        "depth_m": (
            np.zeros((H, W + 1), np.float32),
            f"depth image is {W + 1}x{H}, the dataset's image size",
        ),
        "timings_ms": ((0.0, float("inf"), 0.0, 0.0), "plan timings are not finite"),
    }
    for key, (value, reason) in bad.items():
        status, why = w.record(sample(0, **{key: value}))
        assert status == "rejected" and str(why).startswith(reason), (key, why)
    w.finalize()
    m = yaml.safe_load((tmp_path / "py" / "manifest.yaml").read_text())
    assert m["counts"]["rejected"] == 4 + len(bad) and m["counts"]["written"] == 0 and m["shards"] == []


def test_status_text_is_cut_at_a_character_boundary() -> None:
    assert utf8_prefix("a" * 46 + "é", 47) == b"a" * 46
    assert utf8_prefix("é" * 30, 47) == "é".encode() * 23
    assert utf8_prefix("short", 47) == b"short"


def test_the_writer_refuses_a_directory_holding_a_dataset(tmp_path: Path) -> None:
    DatasetWriter(config(tmp_path / "d")).finalize()
    with pytest.raises(WriterError, match=r"already holds a dataset \(found manifest.yaml\)"):
        DatasetWriter(config(tmp_path / "d"))


DISK_FULL = """
import resource, sys
import numpy as np
sys.path.insert(0, sys.argv[2])
from test_data_writer import config, sample
from quad_il.data.writer import DatasetWriter
from pathlib import Path
w = DatasetWriter(config(Path(sys.argv[1]), shard_size_mb=0.016))  # 2 records (5888 bytes) per shard
statuses = [w.record(sample(i))[0] for i in range(2)]  # shard 0 complete
resource.setrlimit(resource.RLIMIT_FSIZE, (12000, 12000))  # shard 1: its second record is torn
print(statuses + [w.record(sample(i))[0] for i in range(2, 5)])
print(w.finalize(), w.error)
"""


def test_disk_full_stops_the_writer_names_the_file_and_keeps_completed_shards(tmp_path: Path) -> None:
    out = tmp_path / "full"
    # (CPython ignores SIGXFSZ: a write past RLIMIT_FSIZE fails with EFBIG instead of killing the process.)
    proc = subprocess.run(
        [sys.executable, "-c", DISK_FULL, str(out), str(Path(__file__).parent)],
        capture_output=True,
        text=True,
    )
    assert proc.returncode == 0, proc.stderr
    statuses, final = proc.stdout.splitlines()
    assert statuses == "['queued', 'queued', 'queued', 'lost', 'lost']"
    assert final.startswith("False cannot write ") and "File too large" in final
    m = yaml.safe_load((out / "manifest.yaml").read_text())
    assert m["status"] == "incomplete" and "File too large" in m["writer_error"]
    ds = open_dataset(out)
    report = ds.verify()
    assert report.ok, report.format()  # completed shards valid; the torn tail is a warning, not an error
    assert [s.name for s in ds.shards] == ["shard_000000.qdr", "shard_000001.qdr.partial"]
    assert len(ds.shards[0]) == 2 and len(ds.shards[1]) == 1 and ds.shards[1].torn_tail_bytes > 0
    assert m["shards"][0]["records"] == 2 and len(m["shards"]) == 1
    tool = str(find_collector_tool("read_dataset"))
    assert subprocess.run([tool, "verify", str(out)], capture_output=True).returncode == 3  # warnings only
