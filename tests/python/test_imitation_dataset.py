"""The interactive collector's demonstrations: the one dataset format (shards + manifest) with the record
profile of quad_il.imitation.dataset; round trip, episodes appended, what the C++ reader makes of it,
errors."""

from __future__ import annotations

import dataclasses
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from quad_il.data import open_dataset
from quad_il.data.format import DatasetError, decode_depth_codes, encode_depth_m
from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset
from quad_il.imitation import Controller, ImitationError, Observation, Partition, Record, SplineAction
from quad_il.imitation.dataset import (
    RECORD_PROFILE,
    EpisodeWriter,
    episodes,
    read_records,
    read_round,
    shard_records,
    write_dataset,
)


def make_records(n: int = 5, depth: bool = True, features: bool = True, k: int = 6) -> list[Record]:
    rng = np.random.default_rng(1)
    out = []
    for i in range(n):
        q = rng.normal(size=4)
        o = Observation(
            stamp_s=12.0 + 0.1 * i,
            frame_seq=100 + i,
            episode_id=7,
            p_world_body=rng.normal(size=3),
            v_world=rng.normal(size=3),
            q_world_body=q / np.linalg.norm(q),
            goal_world=rng.normal(size=3),
            depth_m=rng.uniform(0, 10, size=(12, 16)).astype(np.float32) if depth else None,
            features=rng.normal(size=9) if features else None,
        )
        label = SplineAction.uniform(rng.normal(size=(k, 3)), 0.25, start_time_s=o.stamp_s, traj_id=i)
        contrast = (
            SplineAction.uniform(rng.normal(size=(k, 3)), 0.25, start_time_s=o.stamp_s) if i % 2 else None
        )
        part = list(Partition)[i % len(Partition)]
        out.append(
            Record(
                obs=o,
                label=label,
                partition=part,
                source="learner" if part in (Partition.GOOD, Partition.BAD) else f"expert_{i}",
                controller=list(Controller)[i % 3],
                round_index=2,
                deviation_m=0.1 * i,
                contrast=contrast,
                score=math.nan if i == 0 else 0.5,
                min_clearance_m=1.5,
            )
        )
    return out


def assert_same(a: Record, b: Record) -> None:
    """b is a's record read back: what the format stores, exactly (depth: its millimetre coding)."""
    for f in ("stamp_s", "episode_id"):
        assert getattr(a.obs, f) == getattr(b.obs, f)
    expected_odom = a.obs.odom_stamp_s if math.isfinite(a.obs.odom_stamp_s) else a.obs.stamp_s
    assert b.obs.odom_stamp_s == expected_odom
    for f in ("p_world_body", "v_world", "q_world_body", "goal_world"):
        np.testing.assert_array_equal(getattr(a.obs, f), getattr(b.obs, f))
    np.testing.assert_array_equal(b.obs.depth_m, decode_depth_codes(encode_depth_m(a.obs.depth_m)))
    assert b.obs.features is None and b.contrast is None  # not stored
    assert a.label.allclose(b.label) and a.label.traj_id == b.label.traj_id
    assert a.label.start_time_s == b.label.start_time_s
    assert (a.partition, a.source, a.controller, a.round_index) == (
        b.partition,
        b.source,
        b.controller,
        b.round_index,
    )
    for f in ("deviation_m", "score", "min_clearance_m"):
        np.testing.assert_equal(getattr(a, f), getattr(b, f))


def test_records_round_trip_with_what_the_format_stores(tmp_path: Path) -> None:
    records = make_records()
    write_dataset(tmp_path / "r", records)
    back = read_records(tmp_path / "r")
    assert len(back) == len(records)
    for i, (a, b) in enumerate(zip(records, back, strict=True)):
        assert_same(a, b)
        assert b.obs.frame_seq == i  # the dataset's seq
    assert math.isnan(back[0].score) and back[1].score == 0.5  # NaN extras stay NaN


def test_episodes_are_appended_and_the_cpp_reader_verifies_the_round(tmp_path: Path) -> None:
    recs = make_records(6)
    first = [dataclasses.replace(r, obs=dataclasses.replace(r.obs, episode_id=3)) for r in recs[:2]]
    second = [dataclasses.replace(r, obs=dataclasses.replace(r.obs, episode_id=4)) for r in recs[2:]]
    w = EpisodeWriter(tmp_path / "r", {"round_index": "2", "algorithm": "dagger"}, fsync=False)
    assert w.write(11, first) == 2
    m = yaml.safe_load((tmp_path / "r" / "manifest.yaml").read_text())
    assert m["status"] == "incomplete" and m["run_info"]["record_profile"] == RECORD_PROFILE
    assert w.write(12, second, camera_fx_px=193.6) == 4  # the dataset exists: its camera stays
    assert w.finalize()
    m = yaml.safe_load((tmp_path / "r" / "manifest.yaml").read_text())
    assert m["status"] == "complete" and m["counts"]["written"] == 6
    assert m["episodes"] == [
        {"episode_id": 3, "world_seed": 11, "records": 2},
        {"episode_id": 4, "world_seed": 12, "records": 4},
    ]
    assert m["run_info"] == {"record_profile": RECORD_PROFILE, "round_index": "2", "algorithm": "dagger"}
    verify = subprocess.run(
        [str(find_collector_tool("read_dataset")), "verify", str(tmp_path / "r")],
        capture_output=True,
        text=True,
    )
    assert verify.returncode == 0, verify.stdout
    data = read_round(tmp_path / "r")
    assert data is not None and data.round_index == 2 and len(data.records) == 6
    assert [len(e) for e in episodes(read_records(tmp_path / "r"))] == [2, 4]
    text = [bytes(t).rstrip(b"\0").decode() for t in data.records["plan_status_text"]]
    assert text[:3] == [f"{r.controller.value} {r.source}" for r in recs[:3]]
    assert data.records["plan_status_code"].tolist() == [0, 1, 2, 3, 0, 1]  # the partition codes


def test_the_in_memory_records_equal_the_written_ones(tmp_path: Path) -> None:
    recs = make_records(4)
    write_dataset(tmp_path / "r", recs, world_seed=0)
    written = read_round(tmp_path / "r")
    assert written is not None
    assert written.records.tobytes() == shard_records(recs).tobytes()


def test_invalid_records_are_refused_and_named(tmp_path: Path) -> None:
    with pytest.raises(ImitationError, match="has no depth image"):
        write_dataset(tmp_path / "a", make_records(2, depth=False))
    with pytest.raises(ImitationError, match="no records to write"):
        write_dataset(tmp_path / "b", [])
    long = make_records(1, k=129)  # more control points than config/collector.yaml's max_ctrl_pts 128
    with pytest.raises(ImitationError, match="B-spline has 129 control points, more than max_ctrl_pts 128"):
        write_dataset(tmp_path / "c", long)
    w = EpisodeWriter(tmp_path / "d", {"round_index": "0"}, fsync=False)
    assert w.write(0, make_records(2) + long) == 2 and len(w.rejected) == 1
    w.finalize()
    m = yaml.safe_load((tmp_path / "d" / "manifest.yaml").read_text())
    assert m["counts"]["rejected"] == 1 and m["counts"]["written"] == 2


def test_foreign_and_missing_datasets_give_clear_answers(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "collector_manifest.json").write_text("{}")
    assert read_round(empty) is None and read_records(empty) == []  # a round that recorded nothing
    cpp = write_synthetic_dataset(tmp_path / "cpp", records=2, width=16, height=12)
    with pytest.raises(DatasetError, match="not an interactive collector's dataset"):
        read_round(cpp)
    with pytest.raises(DatasetError, match="not a directory"):
        read_round(tmp_path / "nope")
    (empty / "episode_000001.npz").write_bytes(b"PK")
    with pytest.raises(
        DatasetError, match=r"episode_\*.npz files of the interactive collector's former format"
    ):
        read_round(empty)


def test_a_torn_tail_left_by_a_killed_collector_is_skipped(tmp_path: Path) -> None:
    w = EpisodeWriter(tmp_path / "r", {"round_index": "1"}, fsync=False)
    w.write(5, make_records(3))
    partial = tmp_path / "r" / "shard_000000.qdr.partial"
    with open(partial, "ab") as fh:  # the collector killed half-way through the next record
        fh.write(b"\x51\x52\x45\x43" + bytes(100))
    ds = open_dataset(tmp_path / "r")
    assert ds.status == "incomplete" and ds.verify().ok
    assert len(read_records(tmp_path / "r")) == 3


def test_records_of_one_episode_may_have_splines_of_different_sizes(tmp_path: Path) -> None:
    recs = make_records(2, k=6) + make_records(1, k=7)
    write_dataset(tmp_path / "r", recs)
    back = read_records(tmp_path / "r")
    assert [r.label.num_ctrl for r in back] == [6, 6, 7]
    for a, b in zip(recs, back, strict=True):
        assert_same(a, b)


def test_odometry_stamp_round_trips(tmp_path: Path) -> None:
    recs = make_records(2)
    obs = dataclasses.replace(recs[0].obs, odom_stamp_s=recs[0].obs.stamp_s - 0.004)
    recs[0] = dataclasses.replace(recs[0], obs=obs)
    write_dataset(tmp_path / "r", recs)
    back = read_records(tmp_path / "r")
    assert back[0].obs.odom_stamp_s == obs.odom_stamp_s
    assert back[1].obs.odom_stamp_s == recs[1].obs.stamp_s  # unknown: the observation's stamp
