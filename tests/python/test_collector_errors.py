"""Bad paths, empty and foreign directories, foreign files and other format versions give clear errors, in the
Python reader and in the C++ `read_dataset` tool."""

from __future__ import annotations

import dataclasses
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

from quad_il.data import (
    CorruptDataError,
    DatasetError,
    EmptyDatasetError,
    FormatVersionError,
    NotADatasetError,
    load_dataset,
    open_dataset,
)
from quad_il.data.format import HEADER_SIZE, parse_shard_header, serialize_shard_header
from quad_il.data.shards import ShardReader
from quad_il.data.synthetic import find_collector_tool, write_synthetic_dataset


@pytest.fixture(scope="module")
def good(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("err") / "good"
    return write_synthetic_dataset(out, seed=3, records=12, width=32, height=24, shard_size_mb=0.03)


@pytest.fixture()
def copy(good: Path, tmp_path: Path) -> Path:
    return Path(shutil.copytree(good, tmp_path / "copy"))


def cpp(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [str(find_collector_tool("read_dataset")), *args], capture_output=True, text=True, check=False
    )


def test_missing_path(tmp_path: Path) -> None:
    with pytest.raises(NotADatasetError, match=r"missing: no such dataset directory"):
        open_dataset(tmp_path / "missing")
    r = cpp("verify", str(tmp_path / "missing"))
    assert r.returncode == 2 and "missing: no such dataset directory" in r.stderr


def test_a_file_instead_of_a_directory(good: Path) -> None:
    with pytest.raises(NotADatasetError, match="not a directory"):
        load_dataset(good / "manifest.yaml")


def test_empty_directory(tmp_path: Path) -> None:
    with pytest.raises(NotADatasetError, match="empty directory, not a quad_il dataset"):
        load_dataset(tmp_path)
    r = cpp("verify", str(tmp_path))
    assert r.returncode == 2 and "empty directory, not a quad_il dataset" in r.stderr


def test_foreign_directory(tmp_path: Path) -> None:
    (tmp_path / "img_0001.png").write_bytes(b"\x89PNG\r\n\x1a\n")
    (tmp_path / "labels.csv").write_text("a,b\n")
    with pytest.raises(
        NotADatasetError, match=r"not a quad_il dataset \(no manifest.yaml and no shard_\*.qdr files\)"
    ):
        open_dataset(tmp_path)
    assert "not a quad_il dataset" in cpp("dump", str(tmp_path)).stderr


def test_foreign_file_named_like_a_shard(tmp_path: Path) -> None:
    (tmp_path / "shard_000000.qdr").write_bytes(b"PK\x03\x04" + bytes(5000))
    with pytest.raises(NotADatasetError, match=r"shard_000000\.qdr: not a quad_il record shard"):
        open_dataset(tmp_path)
    (tmp_path / "shard_000000.qdr").write_bytes(b"")
    with pytest.raises(NotADatasetError, match=r"not a quad_il record shard \(empty file\)"):
        open_dataset(tmp_path)
    with pytest.raises(NotADatasetError, match="no such shard file"):
        ShardReader(tmp_path / "shard_000009.qdr")


def test_shard_of_another_format_version(copy: Path) -> None:
    shard = copy / "shard_000001.qdr"
    data = shard.read_bytes()
    header = parse_shard_header(data[:HEADER_SIZE], "x")
    newer = serialize_shard_header(dataclasses.replace(header, format_version=2))
    shard.write_bytes(newer + data[HEADER_SIZE:])
    with pytest.raises(
        FormatVersionError, match=r"record format version 2 is not supported \(this reader reads version 1\)"
    ):
        load_dataset(copy)
    r = cpp("verify", str(copy))
    assert r.returncode == 2 and "record format version 2 is not supported" in r.stderr


def test_manifest_of_another_format_version(copy: Path) -> None:
    manifest = yaml.safe_load((copy / "manifest.yaml").read_text())
    manifest["format_version"] = 7
    (copy / "manifest.yaml").write_text(yaml.safe_dump(manifest))
    with pytest.raises(FormatVersionError, match="manifest format version 7 is not supported"):
        open_dataset(copy)
    assert "manifest format version 7 is not supported" in cpp("verify", str(copy)).stderr


def test_corrupted_header(copy: Path) -> None:
    shard = copy / "shard_000000.qdr"
    data = bytearray(shard.read_bytes())
    data[300] ^= 0xFF  # inside the layout description
    shard.write_bytes(bytes(data))
    with pytest.raises(CorruptDataError, match=r"shard_000000\.qdr: header CRC mismatch"):
        open_dataset(copy)
    assert "header CRC mismatch" in cpp("verify", str(copy)).stderr


def test_missing_shard_in_the_middle(copy: Path) -> None:
    (copy / "shard_000001.qdr").unlink()
    with pytest.raises(
        CorruptDataError, match=r"shard_000001\.qdr is missing \(next shard found: shard_000002\.qdr\)"
    ):
        open_dataset(copy)


def test_missing_last_shard_is_caught_by_the_manifest(copy: Path) -> None:
    last = sorted(copy.glob("shard_*.qdr"))[-1]
    last.unlink()
    errors = open_dataset(copy).verify().errors
    assert f"manifest lists {last.name} but the file is missing" in errors
    r = cpp("verify", str(copy))
    assert r.returncode == 1 and f"ERROR manifest lists {last.name} but the file is missing" in r.stdout


def test_a_dataset_without_records(tmp_path: Path) -> None:
    empty = write_synthetic_dataset(tmp_path / "none", records=0)
    assert open_dataset(empty).verify().warnings == ["dataset holds no records"]
    with pytest.raises(EmptyDatasetError, match="none: dataset holds no records"):
        load_dataset(empty)


def test_datasets_of_different_image_sizes_are_not_mixed(good: Path, tmp_path: Path) -> None:
    other = write_synthetic_dataset(tmp_path / "big", records=2, width=40, height=30)
    with pytest.raises(DatasetError, match="record layout .* differs"):
        load_dataset([good, other])


def test_no_directory_given() -> None:
    with pytest.raises(NotADatasetError, match="no dataset directory given"):
        load_dataset([])


def test_writer_refuses_a_directory_that_holds_a_dataset(good: Path) -> None:
    with pytest.raises(RuntimeError, match="already holds a dataset"):
        write_synthetic_dataset(good, records=1)
