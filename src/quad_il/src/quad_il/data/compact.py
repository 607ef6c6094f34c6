"""Shrink a dataset's stored depth to the network's input size (docs/data_format.md, "Compacted datasets").

    python -m quad_il.data.compact data/dagger_r1a --out data/dagger_r1a_96 [--size 96x96] [--max-depth-m 10]

The network only ever sees depth through `DepthPreprocessor` (quad_il.learning.preprocessing): REP 118
specials mapped (+inf, NaN -> max_depth_m; -inf -> 0), clamped to [0, max_depth_m], area-resized with
`adaptive_avg_pool2d`, divided, rounded to float16. This tool applies its first two steps once, with the same
torch function (so the cells and their means are the preprocessor's), and stores the result as ordinary
millimetre codes at the target size. The output is a format-version-1 dataset that every reader,
`read_dataset` and training read unchanged; every other record field (seq included) is copied bit for bit,
which the tool checks after writing. Preprocessing the compacted depth gives what preprocessing the source
gives, up to the millimetre code and float16 rounding (the bound: tests/python/test_data_compact.py).

The source must be a complete dataset (finalised or recovered, no partial shard) and is only read; the output
directory must not exist or be empty. There is no in-place mode.

Defaults for --size and --max-depth-m are config/train.yaml's `model.input_width`, `model.input_height` and
`model.max_depth_m` (the file equals the training loader's defaults; read here with YAML, because quad_il.data
must not import quad_il.learning, which imports it: tools/import_cycles.py).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
import yaml

from quad_il.data.format import (
    DEPTH_CODE_TOO_FAR,
    EXTRA_KNOT_SLOTS,
    MANIFEST_NAME,
    DatasetError,
    EmptyDatasetError,
    decode_depth_codes,
)
from quad_il.data.shards import Dataset, open_dataset
from quad_il.data.writer import DatasetWriter, PlanRecordData, WriterConfig
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_path

CHUNK_RECORDS = 128  # records decoded and pooled at a time: ~60 MB of float32 depth at 320x240
# Files beside the shards that other tools read (episode outcomes, run summaries). collect_run.yaml (a
# collection run's identity, for resuming) is not copied: nothing may be appended to a compacted dataset.
SIDE_FILES = ("episodes.csv", "dagger_summary.yaml", "collect_summary.yaml")
# The largest depth an ordinary code holds (code 65534); larger pooled values would become "no return".
MAX_DEPTH_LIMIT_M = (DEPTH_CODE_TOO_FAR - 1) / 1000.0
COMPARED_EXCLUDED = ("depth_code", "crc32")
_SIZE_RE = re.compile(r"^\s*(\d+)\s*[xX]\s*(\d+)\s*$")


class CompactError(DatasetError):
    """The compaction cannot run or its output failed the check; the message names the path and the reason."""


@dataclass(frozen=True)
class CompactSummary:
    src: Path
    dst: Path
    records: int
    src_size: tuple[int, int]  # stored depth (width, height)
    dst_size: tuple[int, int]
    max_depth_m: float
    src_bytes: int  # every file of the directory
    dst_bytes: int
    seconds: float

    @property
    def ratio(self) -> float:
        return self.src_bytes / self.dst_bytes

    def format(self) -> str:
        (sw, sh), (dw, dh) = self.src_size, self.dst_size
        return (
            f"compacted {self.src} -> {self.dst}: {self.records} records, depth {sw}x{sh} -> {dw}x{dh} "
            f"(area-pooled, max_depth_m {_shortest(self.max_depth_m)}), "
            f"written and verified in {self.seconds:.1f} s\n"
            f"{self.src_bytes} bytes -> {self.dst_bytes} bytes ({self.ratio:.2f}x smaller)"
        )


# ------------------------------------------------------------------------------------------------- pieces
def _shortest(v: float) -> str:
    """The shortest decimal that reads back as v, without a trailing '.0' (10.0 -> '10')."""
    text = repr(float(v))
    return text[:-2] if text.endswith(".0") else text


def parse_size(text: str) -> tuple[int, int]:
    """'WIDTHxHEIGHT' (e.g. '96x96') -> (width, height); ValueError naming the text otherwise."""
    m = _SIZE_RE.match(text)
    if not m or int(m[1]) < 1 or int(m[2]) < 1:
        raise ValueError(f"invalid size {text!r}: expected WIDTHxHEIGHT with positive integers, e.g. 96x96")
    return int(m[1]), int(m[2])


def scaled_intrinsics(
    camera: tuple[float, float, float, float], src_size: tuple[int, int], dst_size: tuple[int, int]
) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) of the resized image: focal lengths scale with the size; the principal point keeps its
    place with pixel centres at integer coordinates (cx = (W - 1) / 2 is the centre): cx' = (cx + 0.5) W'/W -
    0.5. A value 0 (unknown) stays 0."""
    sx, sy = dst_size[0] / src_size[0], dst_size[1] / src_size[1]
    fx, fy, cx, cy = camera
    return (
        fx * sx if fx else 0.0,
        fy * sy if fy else 0.0,
        (cx + 0.5) * sx - 0.5 if cx else 0.0,
        (cy + 0.5) * sy - 0.5 if cy else 0.0,
    )


def pool_depth_codes(codes: np.ndarray, width: int, height: int, max_depth_m: float) -> np.ndarray:
    """(N, H, W) uint16 codes -> (N, height, width) float32 metres for the writer's encoder.

    Decoded as the readers do (float32), then exactly DepthPreprocessor's steps 1-2: clamp to [0, max_depth_m]
    (+inf -> max_depth_m, -inf -> 0), NaN -> max_depth_m, `adaptive_avg_pool2d`. The means are finite and in
    [0, max_depth_m], and encode to ordinary codes, except a mean of 0 (a cell of -inf pixels only: finite
    codes are >= 2 mm): the format has no code for 0 m (code 0 is invalid, read as NaN), so it is returned as
    -inf (code 1, too near), which the preprocessor maps back to 0.
    """
    d = torch.from_numpy(decode_depth_codes(codes)).unsqueeze(1)  # a fresh float32 array: modified in place
    d.clamp_(0.0, max_depth_m)
    d.nan_to_num_(nan=max_depth_m)
    pooled = F.adaptive_avg_pool2d(d, [height, width]).squeeze(1).numpy()
    pooled[pooled <= 0.0] = -np.inf
    return pooled


def directory_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.iterdir() if p.is_file())


def training_defaults(config_path: Path | None = None) -> tuple[int, int, float]:
    """(input_width, input_height, max_depth_m) of config/train.yaml's `model` section."""
    path = config_path or repo_path("config", "train.yaml")
    try:
        model = (yaml.safe_load(path.read_text()) or {}).get("model") or {}
        return int(model["input_width"]), int(model["input_height"]), float(model["max_depth_m"])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError, AttributeError) as e:
        raise CompactError(
            f"{path}: cannot read model.input_width, input_height and max_depth_m ({e!r})"
        ) from None


# ----------------------------------------------------------------------------------------------- checks
def _open_complete_source(src: Path) -> Dataset:
    ds = open_dataset(src)
    m = ds.manifest
    if m is None:
        raise CompactError(
            f"{src}: no {MANIFEST_NAME}: only a complete dataset with its manifest is compacted"
        )
    partial = [s.name for s in ds.shards if s.partial]
    if m["status"] not in ("complete", "recovered") or partial:
        raise CompactError(
            f"{src}: dataset is incomplete (manifest status {m['status']}"
            + (f", partial shard {partial[0]}" if partial else "")
            + "): compact only a finished dataset (finalised, or repaired with `read_dataset recover`)"
        )
    listed = [(e["file"], e["records"]) for e in m["shards"] or []]
    present = [(s.name, s.num_records) for s in ds.shards]
    torn = [s.name for s in ds.shards if s.torn_tail_bytes]
    if listed != present or m["counts"]["written"] != len(ds) or torn:
        raise CompactError(
            f"{src}: shards do not match the manifest (listed {len(listed)} shards, {m['counts']['written']} "
            f"records; found {len(present)} shards, {len(ds)} records"
            + (f", torn tail in {torn[0]}" if torn else "")
            + "): run `read_dataset verify` on it"
        )
    if len(ds) == 0 or ds.header is None:
        raise EmptyDatasetError(f"{src}: dataset holds no records: nothing to compact")
    return ds


def _check_output(src: Path, dst: Path) -> None:
    s, d = src.resolve(), dst.resolve()
    if d == s or s in d.parents:
        raise CompactError(f"{dst}: the output must not be the source dataset {src} or inside it")
    if dst.exists() and not dst.is_dir():
        raise CompactError(f"{dst}: output exists and is not a directory")
    if dst.is_dir() and any(dst.iterdir()):
        raise CompactError(
            f"{dst}: output directory exists and is not empty: choose a new directory "
            "(nothing is overwritten)"
        )


def _check_sizes(src: Path, src_size: tuple[int, int], dst_size: tuple[int, int], max_depth_m: float) -> None:
    (sw, sh), (w, h) = src_size, dst_size
    if (w, h) == (sw, sh):
        raise CompactError(f"{src}: stored depth is already {sw}x{sh}, the target size: nothing to do")
    if w > sw or h > sh:
        raise CompactError(
            f"target size {w}x{h} is larger than {src}'s stored depth {sw}x{sh} in "
            + " and ".join(n for n, big in (("width", w > sw), ("height", h > sh)) if big)
            + ": compaction only shrinks (area pooling would upsample)"
        )
    if not 0.0 < max_depth_m <= MAX_DEPTH_LIMIT_M:
        raise CompactError(
            f"max_depth_m {max_depth_m} must be in (0, {MAX_DEPTH_LIMIT_M}] (the codes' range)"
        )


# ----------------------------------------------------------------------------------------------- compact
def _fields_of_range(ds: Dataset, start: int, stop: int, names: Sequence[str]) -> dict[str, np.ndarray]:
    """Copies of the named fields of global records [start, stop), across shard boundaries."""
    parts: dict[str, list[np.ndarray]] = {n: [] for n in names}
    i = start
    while i < stop:
        s, j = ds.locate(i)
        k = min(stop - i, ds.shards[s].num_records - j)
        recs = ds.shards[s].records[j : j + k]
        for n in names:
            parts[n].append(recs[n])
        i += k
    return {n: np.concatenate(v) for n, v in parts.items()}


def _verify_output(src_ds: Dataset, dst: Path, dst_size: tuple[int, int]) -> None:
    """DST is a complete, CRC-clean dataset of the target size, with SRC's record count and every field but
    the depth bit-identical to SRC's, record by record."""
    out = open_dataset(dst)
    report = out.verify()
    if not report.ok or out.status != "complete":
        raise CompactError(f"{dst}: the written dataset fails verification:\n{report.format()}")
    if len(out) != len(src_ds):
        raise CompactError(f"{dst}: holds {len(out)} records, the source {src_ds.path} {len(src_ds)}")
    assert out.header is not None
    if (out.header.image_width, out.header.image_height) != dst_size:
        raise CompactError(f"{dst}: image size {out.header.layout_params[:2]} is not {dst_size}")
    names = [n for n in src_ds.shards[0].dtype.names or () if n not in COMPARED_EXCLUDED]
    for start in range(0, len(out), 8 * CHUNK_RECORDS):
        stop = min(start + 8 * CHUNK_RECORDS, len(out))
        a = _fields_of_range(src_ds, start, stop, names)
        b = _fields_of_range(out, start, stop, names)
        for n in names:
            x = np.ascontiguousarray(a[n]).view(np.uint8).reshape(stop - start, -1)
            y = np.ascontiguousarray(b[n]).view(np.uint8).reshape(stop - start, -1)
            if x.shape != y.shape or not np.array_equal(x, y):
                bad = start + (int(np.flatnonzero((x != y).any(axis=1))[0]) if x.shape == y.shape else 0)
                raise CompactError(f"{dst}: record {bad}: field '{n}' differs from the source's")


def _write(src_ds: Dataset, dst: Path, dst_size: tuple[int, int], max_depth_m: float, progress: bool) -> None:
    from tqdm import tqdm

    m, h = src_ds.manifest, src_ds.header
    assert m is not None and h is not None
    if h.max_knots != h.max_ctrl_pts + EXTRA_KNOT_SLOTS:
        raise CompactError(f"{src_ds.path}: max_knots {h.max_knots} is not max_ctrl_pts + {EXTRA_KNOT_SLOTS}")
    cfg: dict[str, Any] = m["config"]
    fx, fy, cx, cy = scaled_intrinsics(
        (h.camera_fx_px, h.camera_fy_px, h.camera_cx_px, h.camera_cy_px),
        (h.image_width, h.image_height),
        dst_size,
    )
    commit = str(m.get("software_commit") or cfg.get("software_commit") or "")
    config = WriterConfig(
        output_dir=str(dst),
        shard_size_mb=float(cfg["shard_size_mb"]),
        queue_capacity=int(cfg["queue_capacity"]),
        full_queue_policy=str(cfg["full_queue_policy"]),
        image_width=dst_size[0],
        image_height=dst_size[1],
        max_ctrl_pts=h.max_ctrl_pts,
        max_yaw_pts=h.max_yaw_pts,
        fsync=bool(cfg["fsync"]),
        software_commit=commit,
        camera_fx_px=fx,
        camera_fy_px=fy,
        camera_cx_px=cx,
        camera_cy_px=cy,
    )
    run_info = {str(k): str(v) for k, v in (m.get("run_info") or {}).items()}
    run_info["derived_from"] = str(src_ds.path.resolve())
    run_info["compacted"] = f"{dst_size[0]}x{dst_size[1]} area-pooled, max_depth_m {_shortest(max_depth_m)}"
    writer = DatasetWriter(config, run_info)
    w, hgt = dst_size
    with tqdm(
        total=len(src_ds),
        desc=f"compact {src_ds.path.name}",
        unit="rec",
        disable=not progress,
        file=sys.stderr,
    ) as bar:
        for shard, records, indices in src_ds.valid_record_arrays(verify_crc=True, on_corrupt="raise"):
            for start in range(0, len(records), CHUNK_RECORDS):
                chunk = np.array(records[start : start + CHUNK_RECORDS])  # one read of the map
                pooled = pool_depth_codes(chunk["depth_code"], w, hgt, max_depth_m)
                for i, rec in enumerate(chunk):
                    where = f"{shard.path} record {int(indices[start + i])}"
                    try:
                        r = PlanRecordData.from_stored(rec, pooled[i])
                    except UnicodeDecodeError as e:
                        raise CompactError(f"{where}: plan_status_text is not UTF-8 ({e})") from None
                    # A compacted dataset keeps the source's seqs (with the gaps of dropped records).
                    status, value = writer.record(r, seq=int(rec["seq"]))
                    if status != "queued":
                        raise CompactError(f"{where}: the writer {status} the compacted record: {value}")
                bar.update(len(chunk))
    if not writer.finalize():
        raise CompactError(f"{dst}: {writer.error}")


def compact_dataset(
    src: str | os.PathLike[str],
    out: str | os.PathLike[str],
    width: int,
    height: int,
    max_depth_m: float,
    *,
    progress: bool = True,
) -> CompactSummary:
    """Writes SRC's records to OUT with depth area-pooled to width x height (module docstring), checks OUT,
    and returns the summary. Refusals (CompactError / DatasetError, before anything is written): SRC missing,
    not a dataset, incomplete or inconsistent; OUT neither new nor empty, or inside SRC; a target equal to
    SRC's stored size or larger in either dimension. A failure while writing removes what was written."""
    t0 = time.monotonic()
    src_p, dst = Path(src), Path(out)
    src_ds = _open_complete_source(src_p)
    assert src_ds.header is not None
    src_size = (src_ds.header.image_width, src_ds.header.image_height)
    _check_sizes(src_p, src_size, (width, height), max_depth_m)
    _check_output(src_p, dst)
    existed = dst.is_dir()
    try:
        _write(src_ds, dst, (width, height), max_depth_m, progress)
        for name in SIDE_FILES:
            if (src_p / name).is_file():
                shutil.copy2(src_p / name, dst / name)
        _verify_output(src_ds, dst, (width, height))
    except BaseException:
        if existed:  # it was empty: remove what was written into it
            for p in dst.iterdir():
                shutil.rmtree(p) if p.is_dir() else p.unlink()
        else:
            shutil.rmtree(dst, ignore_errors=True)
        raise
    return CompactSummary(
        src=src_ds.path.resolve(),
        dst=dst.resolve(),
        records=len(src_ds),
        src_size=src_size,
        dst_size=(width, height),
        max_depth_m=max_depth_m,
        src_bytes=directory_bytes(src_p),
        dst_bytes=directory_bytes(dst),
        seconds=time.monotonic() - t0,
    )


# -------------------------------------------------------------------------------------------------- CLI
def _size_arg(text: str) -> tuple[int, int]:
    try:
        return parse_size(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def main(argv: Sequence[str] | None = None) -> int:
    try:
        width, height, max_depth_m = training_defaults()
    except (CompactError, OSError) as e:
        print(f"compact: error: {e}", file=sys.stderr)
        return 2
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.data.compact",
        formatter_class=HelpFormatter,
        description=(__doc__ or "").split("\n\n")[0] + "\n\n" + (__doc__ or "").split("\n\n")[1],
    )
    ap.add_argument("src", metavar="SRC", help="complete dataset directory to read (never modified)")
    ap.add_argument(
        "--out",
        required=True,
        metavar="DST",
        help="new or empty output directory (required; no in-place mode)",
    )
    ap.add_argument(
        "--size",
        type=_size_arg,
        metavar="WxH",
        default=f"{width}x{height}",
        help="target depth size WIDTHxHEIGHT (config/train.yaml model.input_width x input_height)",
    )
    ap.add_argument(
        "--max-depth-m",
        type=float,
        default=max_depth_m,
        help="depth clamp, as the network's (config/train.yaml model.max_depth_m)",
    )
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    w, h = args.size
    try:
        summary = compact_dataset(args.src, args.out, w, h, args.max_depth_m, progress=not args.quiet)
    except (DatasetError, OSError) as e:
        print(f"compact: error: {e}", file=sys.stderr)
        return 1
    print(summary.format())
    return 0


if __name__ == "__main__":
    sys.exit(main())
