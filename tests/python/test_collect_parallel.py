"""Parallel collection (quad_il.collection.parallel): seed and episode split, argument errors, refusal to
overwrite, and the learning side reading a collection of worker datasets as one dataset."""

from __future__ import annotations

from pathlib import Path

import pytest

from quad_il.collection.parallel import (
    ParallelError,
    _parse_launch_args,
    parse_seed_ranges,
    plan_workers,
    run_parallel,
)
from quad_il.learning.dataset import expand_paths


def test_seed_ranges_and_lists() -> None:
    assert parse_seed_ranges("100-103,110") == [100, 101, 102, 103, 110]
    assert parse_seed_ranges("1, 2,3") == [1, 2, 3]
    assert parse_seed_ranges("1 2 10-11") == [1, 2, 10, 11]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("5-3", "range '5-3' is empty"),
        ("a-b", "'a-b' is not a range like 100-199"),
        ("1,x", "not a list of integers"),
        ("1-3,2", "a seed is listed twice"),
        (",", "no seed given"),
    ],
)
def test_bad_seeds_name_the_problem(text: str, message: str) -> None:
    with pytest.raises(ParallelError, match=message):
        parse_seed_ranges(text)


def test_plan_deals_seeds_round_robin_and_splits_episodes(tmp_path: Path) -> None:
    plans = plan_workers(list(range(10, 17)), episodes=7, workers=3, out=tmp_path)
    assert [p.seeds for p in plans] == [[10, 13, 16], [11, 14], [12, 15]]
    assert [p.episodes for p in plans] == [3, 2, 2]
    assert [p.out_dir for p in plans] == [tmp_path / f"worker_{k}" for k in range(3)]
    # Every seed flown by exactly one worker.
    assert sorted(s for p in plans for s in p.seeds) == list(range(10, 17))


@pytest.mark.parametrize(
    ("seeds", "episodes", "workers", "message"),
    [
        ([1, 2], 2, 0, "--workers 0: must be >= 1"),
        ([1, 2], 1, 2, "--episodes 1 < --workers 2"),
        ([1], 4, 2, "1 seed\\(s\\) for 2 workers"),
    ],
)
def test_bad_plans(tmp_path: Path, seeds: list[int], episodes: int, workers: int, message: str) -> None:
    with pytest.raises(ParallelError, match=message):
        plan_workers(seeds, episodes, workers, tmp_path)


def test_launch_args() -> None:
    assert _parse_launch_args(["time_mode:=lockstep", "max_samples:=10"]) == {
        "time_mode": "lockstep",
        "max_samples": "10",
    }
    with pytest.raises(ParallelError, match="expected key:=value"):
        _parse_launch_args(["time_mode=lockstep"])
    with pytest.raises(ParallelError, match="--launch-arg seeds: set by the parallel collector"):
        _parse_launch_args(["seeds:=1,2"])


def test_existing_worker_dataset_is_never_overwritten(tmp_path: Path) -> None:
    plans = plan_workers([1, 2], 2, 2, tmp_path)
    (tmp_path / "worker_1").mkdir()
    (tmp_path / "worker_1" / "manifest.yaml").write_text("precious: true\n")
    with pytest.raises(ParallelError, match="worker_1 already exists and is not empty"):
        run_parallel(plans, tmp_path, timeout_s=10)
    assert (tmp_path / "worker_1" / "manifest.yaml").read_text() == "precious: true\n"


def test_collection_directory_expands_to_its_worker_datasets(tmp_path: Path) -> None:
    for k in (1, 0):
        d = tmp_path / f"worker_{k}"
        d.mkdir()
        (d / "manifest.yaml").write_text("x: 1\n")
    (tmp_path / "logs").mkdir()  # not a dataset: ignored
    assert expand_paths([tmp_path]) == [(tmp_path / "worker_0", "shards"), (tmp_path / "worker_1", "shards")]
    # A dataset directory itself stays one source.
    assert expand_paths([tmp_path / "worker_0"]) == [(tmp_path / "worker_0", "shards")]
