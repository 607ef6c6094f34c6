"""Reading cpp_data_collector datasets: memory-mapped shards (no copy), verification, and loading to arrays.

    ds = open_dataset("data/run1")            # validates headers and the manifest, maps every shard
    report = ds.verify()                      # CRC of every record, torn tails, manifest cross-check
    rec = ds.shards[0].records                # numpy structured array viewing the file (read-only, no copy)
    loaded = load_dataset("data/run1")        # all valid records of one or more datasets, as arrays

Format: docs/data_format.md. Errors are DatasetError subclasses whose messages name the path, the shard and
the record index.
"""

from __future__ import annotations

import logging
import os
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from quad_il.data.format import (
    FORMAT_VERSION,
    HEADER_SIZE,
    MANIFEST_NAME,
    RECORD_MAGIC,
    SHARD_NAME_RE,
    CorruptDataError,
    DatasetError,
    EmptyDatasetError,
    FormatVersionError,
    NotADatasetError,
    ShardHeader,
    decode_depth_codes,
    parse_shard_header,
    record_dtype,
)

log = logging.getLogger(__name__)

OnCorrupt = Literal["raise", "skip"]


class ShardReader:
    """One shard file (final or ``*.partial``) memory-mapped as a structured array of complete records.

    Bytes after the last complete record are the torn tail left by a writer killed mid-record: reported by
    ``torn_tail_bytes`` and never part of ``records``.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise NotADatasetError(f"{self.path}: no such shard file")
        if not self.path.is_file():
            raise NotADatasetError(f"{self.path}: not a regular file")
        size = self.path.stat().st_size
        if size == 0:
            raise NotADatasetError(f"{self.path}: not a quad_il record shard (empty file)")
        with open(self.path, "rb") as f:
            head = f.read(HEADER_SIZE)
        self.header: ShardHeader = parse_shard_header(head, str(self.path))
        self.dtype = record_dtype(*self.header.layout_params)
        if self.dtype.itemsize != self.header.record_size:
            raise CorruptDataError(
                f"{self.path}: record size {self.header.record_size} != {self.dtype.itemsize}"
            )
        body = size - HEADER_SIZE
        self.num_records = body // self.header.record_size
        self.torn_tail_bytes = body % self.header.record_size
        self.file_size = size
        # One read-only map of the whole file; `records` is a view of its complete records.
        self._raw: np.ndarray = np.memmap(self.path, dtype=np.uint8, mode="r")
        end = HEADER_SIZE + self.num_records * self.header.record_size
        self.records: np.ndarray = self._raw[HEADER_SIZE:end].view(self.dtype)

    @property
    def name(self) -> str:
        return self.path.name

    @property
    def partial(self) -> bool:
        return self.path.name.endswith(".partial")

    def __len__(self) -> int:
        return self.num_records

    def record_bytes(self, index: int) -> np.ndarray:
        if not 0 <= index < self.num_records:
            raise IndexError(f"{self.name}: record {index} out of range ({self.num_records} records)")
        start = HEADER_SIZE + index * self.header.record_size
        return self._raw[start : start + self.header.record_size]

    def check_record(self, index: int) -> str | None:
        """None when record `index` has the record magic and a matching CRC, else the problem."""
        raw = self.record_bytes(index)
        rs = self.header.record_size
        stored = int(raw[rs - 4 : rs].view("<u4")[0])
        computed = zlib.crc32(raw[: rs - 4])
        if stored != computed:
            return f"CRC mismatch (stored {stored}, computed {computed})"
        if int(raw[:4].view("<u4")[0]) != RECORD_MAGIC:
            return "bad record magic"
        return None

    def bad_records(self) -> list[tuple[int, str]]:
        """(index, problem) of every record failing check_record."""
        out = []
        for i in range(self.num_records):
            problem = self.check_record(i)
            if problem is not None:
                out.append((i, problem))
        return out

    def depth_m(self, index: int, dtype: str = "float32") -> np.ndarray:
        """The depth image of one record in metres (REP 118 specials)."""
        return decode_depth_codes(self.records["depth_code"][index], dtype)

    def close(self) -> None:
        """Drops this reader's references to the map (views handed out earlier keep it alive)."""
        self._raw = np.empty(0, dtype=np.uint8)
        self.records = np.empty(0, dtype=self.dtype)
        self.num_records = 0


@dataclass
class ShardReport:
    name: str
    partial: bool
    records: int
    torn_tail_bytes: int
    bad_records: list[tuple[int, str]] = field(default_factory=list)


@dataclass
class DatasetReport:
    """What verify() found. `errors` are corruption; `warnings` are expected after a crash."""

    path: Path
    status: str
    shards: list[ShardReport]
    valid_records: int
    errors: list[str]
    warnings: list[str]

    @property
    def ok(self) -> bool:
        return not self.errors

    def format(self) -> str:
        lines = [
            f"dataset {self.path}: status {self.status}, {len(self.shards)} shards, "
            f"{self.valid_records} valid records"
        ]
        for s in self.shards:
            lines.append(
                f"  {s.name}: {s.records} records, {len(s.bad_records)} bad, "
                f"torn tail {s.torn_tail_bytes} bytes" + (" (partial)" if s.partial else "")
            )
        lines += [f"WARNING {w}" for w in self.warnings] + [f"ERROR {e}" for e in self.errors]
        return "\n".join(lines)


def read_manifest(path: Path) -> dict[str, Any]:
    """Reads and checks a manifest.yaml (format name and version)."""
    try:
        manifest = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise CorruptDataError(f"{path}: cannot read manifest: {exc}") from None
    if not isinstance(manifest, dict) or manifest.get("format") != "quad_il.cpp_data_collector":
        raise NotADatasetError(f"{path}: not a quad_il cpp_data_collector manifest (missing 'format' key)")
    version = manifest.get("format_version")
    if version != FORMAT_VERSION:
        raise FormatVersionError(
            f"{path}: manifest format version {version} is not supported "
            f"(this reader reads version {FORMAT_VERSION})"
        )
    for key in ("status", "counts", "shards", "config"):
        if key not in manifest:
            raise CorruptDataError(f"{path}: manifest is missing key '{key}'")
    return manifest


class Dataset:
    """A dataset directory: its shards in index order (memory-mapped) and its manifest."""

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise NotADatasetError(f"{self.path}: no such dataset directory")
        if not self.path.is_dir():
            raise NotADatasetError(
                f"{self.path}: not a directory "
                "(pass the dataset directory that holds manifest.yaml and shards)"
            )
        entries = sorted(p.name for p in self.path.iterdir())
        if not entries:
            raise NotADatasetError(f"{self.path}: empty directory, not a quad_il dataset")
        found: dict[int, str] = {}
        for name in entries:
            m = SHARD_NAME_RE.match(name)
            if not m:
                continue
            index = int(m["index"])
            if index in found:
                raise CorruptDataError(
                    f"{self.path}: shard index {index} appears twice ({found[index]} and {name})"
                )
            found[index] = name
        has_manifest = MANIFEST_NAME in entries
        if not has_manifest and not found:
            raise NotADatasetError(
                f"{self.path}: not a quad_il dataset (no manifest.yaml and no shard_*.qdr files)"
            )
        self.manifest: dict[str, Any] | None = (
            read_manifest(self.path / MANIFEST_NAME) if has_manifest else None
        )
        self.shards: list[ShardReader] = []
        for expected, index in enumerate(sorted(found)):
            if index != expected:
                raise CorruptDataError(
                    f"{self.path}: shard_{expected:06d}.qdr is missing (next shard found: {found[index]})"
                )
            shard = ShardReader(self.path / found[index])
            if shard.header.shard_index != index:
                raise CorruptDataError(f"{shard.path}: header says shard index {shard.header.shard_index}")
            if self.shards and shard.header.layout_json != self.shards[0].header.layout_json:
                raise CorruptDataError(f"{shard.path}: record layout differs from {self.shards[0].name}")
            self.shards.append(shard)
        self._offsets = np.cumsum([0] + [s.num_records for s in self.shards])

    @property
    def status(self) -> str:
        return str(self.manifest["status"]) if self.manifest else "(no manifest)"

    @property
    def header(self) -> ShardHeader | None:
        return self.shards[0].header if self.shards else None

    def __len__(self) -> int:
        return int(self._offsets[-1])

    def locate(self, index: int) -> tuple[int, int]:
        """Global record index -> (shard position, index in that shard)."""
        if not 0 <= index < len(self):
            raise IndexError(f"{self.path}: record {index} out of range ({len(self)} records)")
        s = int(np.searchsorted(self._offsets, index, side="right")) - 1
        return s, index - int(self._offsets[s])

    def __getitem__(self, index: int) -> np.void:
        s, i = self.locate(index)
        return self.shards[s].records[i]

    def verify(self) -> DatasetReport:
        """Checks every record's CRC, torn tails and the manifest (the rules of `read_dataset verify`)."""
        errors: list[str] = []
        warnings: list[str] = []
        reports: list[ShardReport] = []
        valid = 0
        m = self.manifest
        if m is None:
            warnings.append("no manifest.yaml: counts and configuration cannot be cross-checked")
        elif m["status"] == "incomplete":
            err = m.get("writer_error") or ""
            warnings.append(
                f"dataset is incomplete: the writer failed: {err}"
                if err
                else "dataset is incomplete: the writer did not finalise it (killed or still running)"
            )
        for pos, shard in enumerate(self.shards):
            rep = ShardReport(
                shard.name, shard.partial, shard.num_records, shard.torn_tail_bytes, shard.bad_records()
            )
            valid += shard.num_records - len(rep.bad_records)
            errors += [f"{shard.name} record {i}: {why}" for i, why in rep.bad_records]
            if shard.torn_tail_bytes:
                what = (
                    f"{shard.name}: torn tail of {shard.torn_tail_bytes} bytes "
                    f"after record {shard.num_records} (skipped)"
                )
                if shard.partial:
                    warnings.append(what)
                else:
                    errors.append(what + " in a completed shard")
            if shard.partial and pos + 1 != len(self.shards):
                errors.append(f"{shard.name}: partial shard is not the last one")
            if shard.partial and m is not None and m["status"] != "incomplete":
                errors.append(f"{shard.name}: partial shard in a {m['status']} dataset")
            reports.append(rep)
        if m is not None:
            by_name = {r.name: r for r in reports}
            for entry in m["shards"] or []:
                rep = by_name.get(entry["file"])
                if rep is None:
                    errors.append(f"manifest lists {entry['file']} but the file is missing")
                elif rep.records != entry["records"]:
                    errors.append(
                        f"{entry['file']}: holds {rep.records} records, the manifest says {entry['records']}"
                    )
            if m["status"] != "incomplete":
                if len(m["shards"] or []) != len(self.shards):
                    errors.append(
                        f"manifest lists {len(m['shards'] or [])} shards, "
                        f"the directory has {len(self.shards)}"
                    )
                if m["counts"]["written"] != len(self):
                    errors.append(
                        f"manifest counts {m['counts']['written']} written records, shards hold {len(self)}"
                    )
            if self.header is not None and (
                m["config"]["image_width"] != self.header.image_width
                or m["config"]["image_height"] != self.header.image_height
            ):
                errors.append("manifest image size differs from the shard headers")
        if not self.shards:
            warnings.append("dataset holds no records")
        return DatasetReport(self.path, self.status, reports, valid, errors, warnings)

    def valid_record_arrays(
        self, *, verify_crc: bool = True, on_corrupt: OnCorrupt = "raise"
    ) -> Iterator[tuple[ShardReader, np.ndarray, np.ndarray]]:
        """Per shard: (shard, records, indices) of its usable records (views when nothing is skipped).

        Torn tails of partial shards are logged and skipped. Corruption (a CRC mismatch, a torn tail in a
        completed shard) raises CorruptDataError naming shard and record, or with on_corrupt="skip" is logged
        and skipped.
        """
        for shard in self.shards:
            if shard.torn_tail_bytes:
                msg = (
                    f"{self.path / shard.name}: torn tail of {shard.torn_tail_bytes} bytes after record "
                    f"{shard.num_records}"
                )
                if shard.partial:
                    log.warning("%s (skipped: the writer was killed mid-record)", msg)
                elif on_corrupt == "raise":
                    raise CorruptDataError(msg + " in a completed shard (truncated file?)")
                else:
                    log.warning("%s in a completed shard (skipped)", msg)
            indices = np.arange(shard.num_records)
            records = shard.records
            if verify_crc:
                bad = shard.bad_records()
                if bad and on_corrupt == "raise":
                    i, why = bad[0]
                    raise CorruptDataError(f"{self.path / shard.name} record {i}: {why}")
                for i, why in bad:
                    log.warning("%s record %d: %s (skipped)", self.path / shard.name, i, why)
                if bad:
                    keep = np.ones(shard.num_records, dtype=bool)
                    keep[[i for i, _ in bad]] = False
                    indices = indices[keep]
                    records = records[keep]
            yield shard, records, indices


def open_dataset(path: str | os.PathLike[str]) -> Dataset:
    """Opens a dataset directory (see Dataset)."""
    return Dataset(path)


@dataclass(frozen=True)
class LoadedRecords:
    """Valid records of one or more datasets, concatenated (an in-memory copy).

    `records` has the shard record dtype (docs/data_format.md; e.g. records["p_world_body"] is (N, 3)).
    `source` maps each record back to (dataset path, shard name, index in shard) for error messages.
    """

    records: np.ndarray
    shard_names: tuple[str, ...]
    source_shard: np.ndarray  # int32 (N,): index into shard_names
    source_index: np.ndarray  # int64 (N,): record index inside its shard
    headers: tuple[ShardHeader, ...]
    manifests: tuple[dict[str, Any] | None, ...]

    def __post_init__(self) -> None:
        n = len(self.records)
        if self.source_shard.shape != (n,) or self.source_index.shape != (n,):
            raise ValueError("source arrays must have one entry per record")

    def __len__(self) -> int:
        return len(self.records)

    def __getitem__(self, name: str) -> np.ndarray:
        return self.records[name]

    def source(self, i: int) -> str:
        return f"{self.shard_names[int(self.source_shard[i])]} record {int(self.source_index[i])}"

    def depth_m(self, dtype: str = "float32") -> np.ndarray:
        """(N, H, W) depth in metres (REP 118 specials)."""
        return decode_depth_codes(self.records["depth_code"], dtype)


def load_dataset(
    paths: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
    *,
    verify_crc: bool = True,
    on_corrupt: OnCorrupt = "raise",
) -> LoadedRecords:
    """Loads every valid record of one or more dataset directories into memory.

    Raises NotADatasetError / FormatVersionError / CorruptDataError (see Dataset and valid_record_arrays),
    EmptyDatasetError when there is no record, DatasetError when datasets differ in layout (image size...).
    """
    if isinstance(paths, str | os.PathLike):
        paths = [paths]
    if not paths:
        raise NotADatasetError("no dataset directory given")
    chunks: list[np.ndarray] = []
    names: list[str] = []
    src_shard: list[np.ndarray] = []
    src_index: list[np.ndarray] = []
    headers: list[ShardHeader] = []
    manifests: list[dict[str, Any] | None] = []
    for path in paths:
        ds = open_dataset(path)
        manifests.append(ds.manifest)
        if ds.header is not None:
            if headers and ds.header.layout_params != headers[0].layout_params:
                raise DatasetError(
                    f"{ds.path}: record layout {ds.header.layout_params} (width, height, max knots, control "
                    f"and yaw points) differs from {paths[0]}'s {headers[0].layout_params}"
                )
            headers.append(ds.header)
        for shard, records, indices in ds.valid_record_arrays(verify_crc=verify_crc, on_corrupt=on_corrupt):
            names.append(str(ds.path / shard.name))
            chunks.append(np.array(records))  # copy out of the map
            src_shard.append(np.full(len(records), len(names) - 1, dtype=np.int32))
            src_index.append(indices.astype(np.int64))
    total = sum(len(c) for c in chunks)
    if total == 0:
        where = ", ".join(str(p) for p in paths)
        raise EmptyDatasetError(f"{where}: dataset holds no records")
    return LoadedRecords(
        records=np.concatenate(chunks),
        shard_names=tuple(names),
        source_shard=np.concatenate(src_shard),
        source_index=np.concatenate(src_index),
        headers=tuple(headers),
        manifests=tuple(manifests),
    )
