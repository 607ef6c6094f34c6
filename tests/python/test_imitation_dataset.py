"""The Python collector's episode files: round trip, atomic writes, torn and foreign files."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from quad_il.imitation import Controller, ImitationError, Observation, Partition, Record, SplineAction
from quad_il.imitation.dataset import (
    DatasetError,
    episode_filename,
    list_episodes,
    read_episode,
    records_to_arrays,
    write_episode,
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
    for f in ("stamp_s", "frame_seq", "episode_id"):
        assert getattr(a.obs, f) == getattr(b.obs, f)
    for f in ("p_world_body", "v_world", "q_world_body", "goal_world"):
        np.testing.assert_array_equal(getattr(a.obs, f), getattr(b.obs, f))
    for f in ("depth_m", "features"):
        x, y = getattr(a.obs, f), getattr(b.obs, f)
        assert (x is None) == (y is None)
        if x is not None:
            np.testing.assert_array_equal(x, y)
    assert a.label.allclose(b.label) and a.label.traj_id == b.label.traj_id
    assert (a.contrast is None) == (b.contrast is None)
    if a.contrast is not None and b.contrast is not None:
        assert a.contrast.allclose(b.contrast)
    assert (a.partition, a.source, a.controller, a.round_index) == (
        b.partition,
        b.source,
        b.controller,
        b.round_index,
    )
    for f in ("deviation_m", "score", "min_clearance_m"):
        np.testing.assert_equal(getattr(a, f), getattr(b, f))


@pytest.mark.parametrize(("depth", "features"), [(True, True), (False, False)])
def test_records_round_trip_exactly(tmp_path: Path, depth: bool, features: bool) -> None:
    records = make_records(depth=depth, features=features)
    path = write_episode(tmp_path, 7, records)
    assert path.name == episode_filename(7) == "episode_000007.npz"
    back = read_episode(path)
    assert len(back) == len(records)
    for a, b in zip(records, back, strict=True):
        assert_same(a, b)
    assert list_episodes(tmp_path) == ([path], [])


def test_write_leaves_no_partial_file_and_refuses_to_overwrite(tmp_path: Path) -> None:
    write_episode(tmp_path, 1, make_records(2))
    assert not list(tmp_path.glob("*.partial"))
    with pytest.raises(DatasetError, match="already exists"):
        write_episode(tmp_path, 1, make_records(2))


def test_torn_partial_files_are_reported_and_never_read(tmp_path: Path) -> None:
    path = write_episode(tmp_path, 1, make_records(2))
    torn = tmp_path / "episode_000002.npz.partial"
    torn.write_bytes(path.read_bytes()[:100])
    assert list_episodes(tmp_path) == ([path], [torn])
    with pytest.raises(DatasetError, match="incomplete"):
        read_episode(torn)


def test_truncated_foreign_and_future_files_give_clear_errors(tmp_path: Path) -> None:
    path = write_episode(tmp_path, 1, make_records(2))
    cut = tmp_path / "episode_000003.npz"
    cut.write_bytes(path.read_bytes()[:200])
    with pytest.raises(DatasetError, match="episode_000003.npz: not a readable .npz"):
        read_episode(cut)
    arrays = records_to_arrays(make_records(2))
    arrays["format_version"] = np.array(99)
    future = tmp_path / "future.npz"
    np.savez(future, **arrays)
    with pytest.raises(DatasetError, match=r"format_version 99, this reader understands \[1, 2\]"):
        read_episode(future)
    del arrays["partition"]
    arrays["format_version"] = np.array(2)
    np.savez(tmp_path / "missing.npz", **arrays)
    with pytest.raises(DatasetError, match="missing field 'partition'"):
        read_episode(tmp_path / "missing.npz")
    with pytest.raises(DatasetError, match="not a directory"):
        list_episodes(tmp_path / "nope")


def test_records_of_one_episode_may_have_splines_of_different_sizes(tmp_path: Path) -> None:
    recs = make_records(2, k=6) + make_records(1, k=7)
    path = write_episode(tmp_path, 1, recs)
    back = read_episode(path)
    assert [r.label.num_ctrl for r in back] == [6, 6, 7]
    for a, b in zip(recs, back, strict=True):
        assert_same(a, b)
    with np.load(path) as data:
        assert data["label_ctrl"].shape[1] == 7 and data["label_num_ctrl"].tolist() == [6, 6, 7]
        arrays = {k: data[k] for k in data.files}
    arrays["label_num_ctrl"] = np.array([6, 6, 9])
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(DatasetError, match="record 2: label_num_ctrl 9 with order 3 does not fit"):
        read_episode(tmp_path / "bad.npz")
    with pytest.raises(ImitationError, match="no records"):
        write_episode(tmp_path, 2, [])


def test_version_1_files_are_still_read(tmp_path: Path) -> None:
    recs = make_records(2)
    arrays = records_to_arrays(recs)
    for key in ("label_num_ctrl", "odom_stamp_s"):
        del arrays[key]
    arrays["format_version"] = np.array(1)
    np.savez(tmp_path / "v1.npz", **arrays)
    back = read_episode(tmp_path / "v1.npz")
    for a, b in zip(recs, back, strict=True):
        assert_same(a, b)
        assert np.isnan(b.obs.odom_stamp_s)


def test_odometry_stamp_round_trips(tmp_path: Path) -> None:
    recs = make_records(2)
    obs = dataclasses.replace(recs[0].obs, odom_stamp_s=recs[0].obs.stamp_s - 0.004)
    recs[0] = dataclasses.replace(recs[0], obs=obs)
    back = read_episode(write_episode(tmp_path, 3, recs))
    assert back[0].obs.odom_stamp_s == obs.odom_stamp_s and np.isnan(back[1].obs.odom_stamp_s)
