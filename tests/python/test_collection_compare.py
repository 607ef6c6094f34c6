"""`python -m quad_il.collection.compare`: the digest of a dataset's records without the wall-clock fields
(issue 31's before/after check of a collection) and the differences between two datasets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quad_il.collection.compare import (
    TIMING_FIELDS,
    compare_records,
    dataset_records,
    main,
    records_digest,
)
from quad_il.data.synthetic import write_synthetic_dataset


@pytest.fixture(scope="module")
def two_datasets(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Path]:
    base = tmp_path_factory.mktemp("compare")
    a = write_synthetic_dataset(base / "a", seed=4, records=12, width=16, height=12, records_per_episode=6)
    b = write_synthetic_dataset(base / "b", seed=4, records=12, width=16, height=12, records_per_episode=6)
    c = write_synthetic_dataset(base / "c", seed=5, records=12, width=16, height=12, records_per_episode=6)
    return a, b, c


def test_the_digest_ignores_only_the_wall_clock_fields(two_datasets: tuple[Path, Path, Path]) -> None:
    a, _, _ = two_datasets
    r = dataset_records(a)
    digest = records_digest(r)
    timed = r.copy()
    timed[TIMING_FIELDS[0]] += 1.0  # another run's CPU time: same records
    assert records_digest(timed) == digest
    moved = r.copy()
    moved["p_world_body"][3, 0] = np.nextafter(moved["p_world_body"][3, 0], np.inf)  # one bit of one field
    assert records_digest(moved) != digest
    assert compare_records(r, moved)[0].startswith("record 3 field p_world_body")


def test_the_command_prints_digests_and_exits_by_the_differences(
    two_datasets: tuple[Path, Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    a, b, c = two_datasets
    assert main([str(a), str(b)]) == 0
    out = capsys.readouterr().out
    assert out.count("12 records, sha256 without timing fields") == 2 and "differences: none" in out
    assert main([str(a), str(c)]) == 1
    assert "differences: \n  record" in capsys.readouterr().out
    assert main([str(a / "missing")]) == 2
    assert "no such dataset directory" in capsys.readouterr().err
