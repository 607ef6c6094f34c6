"""A Python writer of the cpp_data_collector dataset format, version 1 (docs/data_format.md): the same
shards, byte for byte, and the same manifest as the C++ `DatasetWriter` for the same records.

    w = DatasetWriter(WriterConfig(output_dir="data/round_000", image_width=320, image_height=240, ...))
    w.record(PlanRecordData(...))  # validated as the C++ writer does: ("queued", seq) or ("rejected", why)
    w.flush()                      # fsync the open shard (the end of an episode)
    w.finalize()                   # complete the open shard, manifest status: complete

It exists because the interactive (DAgger) collector is a Python node: it writes its demonstrations in the
one format every reader of the project reads (quad_il.data.shards, `read_dataset`), through this twin of the
C++ writer. A twin, not a binding: the C++ writer is a queue and a thread tuned for the planner's latency;
here records come once per episode. Held together by tests/python/test_data_writer.py: shards
byte-identical to `write_synthetic_dataset`'s for the same records, each side's output read by the other
side's reader, the same rejections with the same reasons.

Differences from the C++ writer, on purpose: records are written synchronously (no queue: nothing is
dropped; `queue_capacity` and `full_queue_policy` are only recorded in the manifest), and there is no append
mode. Crash safety is the C++ writer's: records are appended to `shard_NNNNNN.qdr.partial`, a shard is
fsynced and renamed when full, the manifest says `incomplete` until `finalize()`; an I/O error (disk full)
stops the writer with the error in the manifest's `writer_error`, the partial shard keeps its name and its
torn tail is reported and skipped by both readers.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from quad_il.data.format import (
    DEPTH_ENCODING_UINT16_MM,
    EXTRA_KNOT_SLOTS,
    FORMAT_VERSION,
    HEADER_SIZE,
    MANIFEST_NAME,
    RECORD_MAGIC,
    STATUS_TEXT_BYTES,
    DatasetError,
    ShardHeader,
    decode_depth_codes,
    encode_depth_m,
    layout_json,
    record_dtype,
    serialize_shard_header,
)

MAX_SPLINE_ORDER = 7
MAX_LISTED_DROPS = 1000
PARTIAL_SUFFIX = ".partial"


class WriterError(DatasetError):
    """The writer cannot go on (output directory, I/O error); the message names the path."""


@dataclass(frozen=True)
class WriterConfig:
    """The C++ WriterConfig's keys (docs/cpp_data_collector.md), every one given: no defaults."""

    output_dir: str
    shard_size_mb: float
    queue_capacity: int
    full_queue_policy: str
    image_width: int
    image_height: int
    max_ctrl_pts: int
    max_yaw_pts: int
    fsync: bool
    software_commit: str
    camera_fx_px: float
    camera_fy_px: float
    camera_cx_px: float
    camera_cy_px: float

    def __post_init__(self) -> None:
        if not self.shard_size_mb > 0 or not math.isfinite(self.shard_size_mb):
            raise ValueError(f"shard_size_mb must be finite and > 0, got {self.shard_size_mb}")
        if self.image_width < 1 or self.image_height < 1:
            raise ValueError(f"image size {self.image_width}x{self.image_height} must be positive")
        if self.max_ctrl_pts < 2:
            raise ValueError(f"max_ctrl_pts must be >= 2, got {self.max_ctrl_pts}")
        if self.max_yaw_pts < 0:
            raise ValueError(f"max_yaw_pts must be >= 0, got {self.max_yaw_pts}")
        if self.full_queue_policy not in ("block", "drop"):
            raise ValueError(f"full_queue_policy must be block or drop, got {self.full_queue_policy!r}")


@dataclass(frozen=True, eq=False)
class PlanRecordData:
    """One record's inputs (the C++ PlanRecord): the observation, the plan, its status and timings."""

    episode_id: int
    world_seed: int
    sim_time_s: float
    depth_m: np.ndarray  # (H, W) float32 metres, REP 118 specials
    depth_stamp_s: float
    odom_stamp_s: float
    p_world_body: Sequence[float]
    v_world: Sequence[float]
    q_world_body: Sequence[float]  # x, y, z, w
    w_body: Sequence[float]
    goal_world: Sequence[float]
    order: int
    traj_id: int
    start_time_s: float
    knots: Sequence[float]
    ctrl_pts_world: np.ndarray  # (n, 3)
    yaw_pts: Sequence[float] = ()
    yaw_dt_s: float = 0.0
    status_code: int = 0
    status_text: str = ""
    timings_ms: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # map, frontend, optimisation, total
    flags: int = 0

    @classmethod
    def from_stored(cls, rec: np.void, depth_m: np.ndarray | None = None) -> PlanRecordData:
        """A stored record (quad_il.data.shards) back into the writer's input: every field as stored, the
        depth decoded from its codes (which re-encodes to them exactly) unless another image is given.
        UnicodeDecodeError for a status text that is not UTF-8."""
        names = rec.dtype.names or ()
        n, nk, ny = int(rec["num_ctrl_pts"]), int(rec["num_knots"]), int(rec["num_yaw_pts"])
        return cls(
            episode_id=int(rec["episode_id"]),
            world_seed=int(rec["world_seed"]),
            sim_time_s=float(rec["sim_time_s"]),
            depth_m=decode_depth_codes(rec["depth_code"]) if depth_m is None else depth_m,
            depth_stamp_s=float(rec["depth_stamp_s"]),
            odom_stamp_s=float(rec["odom_stamp_s"]),
            p_world_body=rec["p_world_body"],
            v_world=rec["v_world"],
            q_world_body=rec["q_world_body"],
            w_body=rec["w_body"],
            goal_world=rec["goal_world"],
            order=int(rec["bspline_order"]),
            traj_id=int(rec["bspline_traj_id"]),
            start_time_s=float(rec["bspline_start_time_s"]),
            knots=rec["knots"][:nk],
            ctrl_pts_world=rec["ctrl_pts_world"][:n],
            yaw_pts=rec["yaw_pts"][:ny] if "yaw_pts" in names else (),
            yaw_dt_s=float(rec["bspline_yaw_dt_s"]),
            status_code=int(rec["plan_status_code"]),
            status_text=bytes(rec["plan_status_text"]).rstrip(b"\0").decode("utf-8"),
            timings_ms=(
                float(rec["t_map_update_ms"]),
                float(rec["t_frontend_ms"]),
                float(rec["t_optimization_ms"]),
                float(rec["t_total_ms"]),
            ),
            flags=int(rec["flags"]),
        )


def validate(r: PlanRecordData, cfg: WriterConfig) -> str:
    """'' for a valid record, else why not (the C++ ValidatePlanRecord's rules and messages)."""
    d = np.asarray(r.depth_m)
    if d.size == 0:
        return "depth image has no data"
    if d.ndim != 2 or d.shape != (cfg.image_height, cfg.image_width):
        h, w = (d.shape + (0, 0))[:2] if d.ndim >= 2 else (0, d.size)
        return f"depth image is {w}x{h}, the dataset's image size is {cfg.image_width}x{cfg.image_height}"

    def finite(v: Sequence[float] | np.ndarray | float) -> bool:
        return bool(np.all(np.isfinite(np.asarray(v, dtype=np.float64))))

    if not finite(r.depth_stamp_s):
        return "depth stamp is not finite"
    if not finite(r.sim_time_s):
        return "sim_time_s is not finite"
    if not all(finite(v) for v in (r.odom_stamp_s, r.p_world_body, r.v_world, r.q_world_body, r.w_body)):
        return "odometry has a non-finite value"
    qn = float(np.sqrt(np.sum(np.square(np.asarray(r.q_world_body, dtype=np.float64)))))
    if abs(qn - 1.0) > 1e-3:
        return f"odometry quaternion has norm {qn:.6f}, not 1"
    if not finite(r.goal_world):
        return "goal has a non-finite value"
    if r.order < 1 or r.order > MAX_SPLINE_ORDER:
        return f"B-spline order {r.order} is outside [1, {MAX_SPLINE_ORDER}]"
    ctrl = np.asarray(r.ctrl_pts_world, dtype=np.float64).reshape(-1, 3)
    knots = np.asarray(r.knots, dtype=np.float64)
    n, p = len(ctrl), int(r.order)
    if n < p + 1:
        return f"B-spline has {n} control points, fewer than order + 1"
    if n > cfg.max_ctrl_pts:
        return f"B-spline has {n} control points, more than max_ctrl_pts {cfg.max_ctrl_pts}"
    if len(knots) != n + p + 1:
        return f"B-spline has {len(knots)} knots, expected control points + order + 1 = {n + p + 1}"
    if not finite(knots):
        return "B-spline knots are not finite"
    dec = np.nonzero(np.diff(knots) < 0)[0]
    if dec.size:
        return f"B-spline knots decrease at index {int(dec[0]) + 1}"
    if not knots[p] < knots[n]:
        return "B-spline has an empty parameter domain (knots[order] >= knots[n])"
    if not finite(ctrl):
        return "B-spline control point is not finite"
    if len(r.yaw_pts) > cfg.max_yaw_pts:
        return f"B-spline has {len(r.yaw_pts)} yaw points, more than max_yaw_pts {cfg.max_yaw_pts}"
    if not finite(list(r.yaw_pts)):
        return "B-spline yaw points are not finite"
    if not math.isfinite(r.yaw_dt_s) or r.yaw_dt_s < 0.0 or (len(r.yaw_pts) and r.yaw_dt_s <= 0.0):
        return f"B-spline yaw_dt_s {r.yaw_dt_s} must be finite and > 0 (>= 0 without yaw)"
    if not finite(r.start_time_s):
        return "B-spline start time is not finite"
    if not finite(list(r.timings_ms)):
        return "plan timings are not finite"
    return ""


def utf8_prefix(text: str, max_bytes: int) -> bytes:
    """`text` in UTF-8, cut to at most max_bytes without splitting a character (the C++ writer's rule)."""
    raw = text.encode("utf-8")
    if len(raw) <= max_bytes:
        return raw
    n = max_bytes
    while n > 0 and (raw[n] & 0xC0) == 0x80:
        n -= 1
    return raw[:n]


def layout_params(cfg: WriterConfig) -> tuple[int, int, int, int, int]:
    """(width, height, max knots, max control points, max yaw points) of the config's records."""
    return (
        cfg.image_width,
        cfg.image_height,
        cfg.max_ctrl_pts + EXTRA_KNOT_SLOTS,
        cfg.max_ctrl_pts,
        cfg.max_yaw_pts,
    )


def encode_record(r: PlanRecordData, seq: int, dtype: np.dtype) -> bytes:
    """One record's bytes with its CRC (unused slots and padding zero): the C++ writer's Fill + WriteRecord.
    The record must have passed `validate`."""
    rec = np.zeros(1, dtype=dtype)
    ctrl = np.asarray(r.ctrl_pts_world, dtype=np.float64).reshape(-1, 3)
    knots = np.asarray(r.knots, dtype=np.float64)
    yaw = np.asarray(r.yaw_pts, dtype=np.float64)
    values = {
        "magic": RECORD_MAGIC,
        "flags": r.flags,
        "seq": seq,
        "episode_id": r.episode_id,
        "world_seed": r.world_seed,
        "sim_time_s": r.sim_time_s,
        "depth_stamp_s": r.depth_stamp_s,
        "odom_stamp_s": r.odom_stamp_s,
        "p_world_body": r.p_world_body,
        "v_world": r.v_world,
        "q_world_body": r.q_world_body,
        "w_body": r.w_body,
        "goal_world": r.goal_world,
        "bspline_start_time_s": r.start_time_s,
        "bspline_yaw_dt_s": r.yaw_dt_s,
        "bspline_traj_id": r.traj_id,
        "bspline_order": r.order,
        "num_knots": len(knots),
        "num_ctrl_pts": len(ctrl),
        "num_yaw_pts": len(yaw),
        "plan_status_code": r.status_code,
        "t_map_update_ms": r.timings_ms[0],
        "t_frontend_ms": r.timings_ms[1],
        "t_optimization_ms": r.timings_ms[2],
        "t_total_ms": r.timings_ms[3],
        "plan_status_text": utf8_prefix(r.status_text, STATUS_TEXT_BYTES - 1),
    }
    for k, v in values.items():
        rec[k] = v
    rec["knots"][0, : len(knots)] = knots
    rec["ctrl_pts_world"][0, : len(ctrl)] = ctrl
    if len(yaw):
        rec["yaw_pts"][0, : len(yaw)] = yaw
    rec["depth_code"][0] = encode_depth_m(r.depth_m)
    raw = bytearray(rec.tobytes())
    size = dtype.itemsize
    raw[size - 4 :] = zlib.crc32(raw[: size - 4]).to_bytes(4, "little")
    return bytes(raw)


def load_writer_config(path: str | os.PathLike[str], **replace: object) -> WriterConfig:
    """The C++ writer's YAML (config/collector.yaml), strictly: every key, no other; `replace` sets keys the
    caller owns (output_dir, image size, camera_*_px, software_commit), as the C++ collector's node does."""
    p = Path(path)
    try:
        data = yaml.safe_load(p.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise WriterError(f"{p}: cannot read the writer config: {e}") from None
    keys = {f.name for f in dataclasses.fields(WriterConfig)}
    camera_keys = {"fx_px", "fy_px", "cx_px", "cy_px"}
    if not isinstance(data, dict):
        raise WriterError(f"{p}: the writer config must be a mapping")
    flat = {k: v for k, v in data.items() if k != "camera"}
    cam = data.get("camera")
    if not isinstance(cam, dict) or set(cam) != camera_keys:
        raise WriterError(f"{p}: 'camera' must hold exactly {sorted(camera_keys)}")
    flat.update({f"camera_{k}": v for k, v in cam.items()})
    unknown, missing = sorted(set(flat) - keys), sorted(keys - set(flat))
    if unknown or missing:
        raise WriterError(f"{p}: unknown keys {unknown}, missing keys {missing}")
    flat.update(replace)
    try:
        return WriterConfig(**flat)  # type: ignore[arg-type]
    except (TypeError, ValueError) as e:
        raise WriterError(f"{p}: {e}") from None


def utc_now_iso8601() -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


def _shortest(v: float) -> str:
    """The shortest decimal that reads back as the same double (as the C++ manifest's std::to_chars)."""
    text = repr(float(v))
    return text[:-2] if text.endswith(".0") else text


def _plain_or_quoted(text: str) -> str:
    """A plain YAML scalar where that reads back as the same string (as yaml-cpp emits it), else quoted."""
    plain = re.fullmatch(r"[A-Za-z0-9_./][A-Za-z0-9_./+-]*", text) is not None
    return (
        text
        if plain and text.lower() not in ("true", "false", "null", "yes", "no", "on", "off")
        else _quoted(text)
    )


def _quoted(text: str) -> str:
    out = text.replace("\\", "\\\\").replace('"', '\\"')
    return f'"{out}"'


@dataclass
class _Shard:
    file: str
    index: int
    records: int = 0
    bytes: int = 0
    first_seq: int = 0
    last_seq: int = 0


@dataclass
class _Episode:
    episode_id: int
    world_seed: int
    records: int


@dataclass
class WriterCounts:
    submitted: int = 0
    written: int = 0
    dropped: int = 0
    rejected: int = 0
    lost: int = 0
    rejections: list[str] = field(default_factory=list)  # the first reasons, for logs


class DatasetWriter:
    def __init__(self, config: WriterConfig, run_info: dict[str, str] | None = None) -> None:
        self.config = config
        out = Path(config.output_dir)
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise WriterError(
                f"dataset writer: cannot create output directory '{out}': {e.strerror}"
            ) from None
        for p in out.iterdir():
            if p.name == MANIFEST_NAME or p.name.startswith("shard_"):
                raise WriterError(
                    f"dataset writer: output directory '{out}' already holds a dataset (found {p.name}); "
                    "choose a new directory"
                )
        self.dir = Path(os.path.normpath(os.path.abspath(out)))
        self.layout = layout_params(config)
        self.dtype = record_dtype(*self.layout)
        self.record_size = self.dtype.itemsize
        usable = config.shard_size_mb * 1e6 - HEADER_SIZE
        self.records_per_shard = max(1, int(usable / self.record_size)) if usable > 0 else 1
        self.counts = WriterCounts()
        self.run_info: dict[str, str] = {str(k): str(v) for k, v in (run_info or {}).items()}
        self.created_utc = utc_now_iso8601()
        self.error = ""
        self.finalized = False
        self._next_seq = 0
        self._fd = -1
        self._current: _Shard | None = None
        self._completed: list[_Shard] = []
        self._episodes: dict[int, _Episode] = {}
        self._write_manifest("incomplete")

    # ---- records ----
    def record(self, r: PlanRecordData, seq: int | None = None) -> tuple[str, int | str]:
        """("queued", seq) once written; ("rejected", reason) for an invalid record (counted, not written);
        ("lost", error) after an I/O error stopped the writer; WriterError after finalize(). `seq`: the
        record's sequence number when it is copied from another dataset (quad_il.data.compact keeps the
        source's, gaps included; must exceed the previous record's); by default the next one."""
        if self.finalized:
            raise WriterError(f"{self.dir}: record() called after finalize()")
        why = validate(r, self.config)
        if why:
            self.counts.rejected += 1
            if len(self.counts.rejections) < 10:
                self.counts.rejections.append(why)
            return "rejected", why
        if self.error:
            self.counts.lost += 1
            return "lost", self.error
        if seq is not None and seq < self._next_seq:
            raise WriterError(
                f"{self.dir}: seq {seq} is not after the previous record's {self._next_seq - 1}"
            )
        seq = self._next_seq if seq is None else seq
        self._next_seq = seq + 1
        self.counts.submitted += 1
        try:
            self._write(r, seq)
        except OSError as e:
            self._fail(e)
            self.counts.lost += 1
            return "lost", self.error
        return "queued", seq

    def set_run_info(self, key: str, value: str) -> None:
        """A free key/value string of the manifest's run_info (kept in insertion order, as the C++ writer)."""
        self.run_info[str(key)] = str(value)

    def flush(self) -> None:
        """fsync the open shard (with `fsync`) and rewrite the manifest (still incomplete)."""
        if self.error:
            return
        try:
            if self._fd >= 0 and self.config.fsync:
                os.fsync(self._fd)
            self._write_manifest("incomplete")
        except OSError as e:
            self._fail(e)

    def finalize(self) -> bool:
        """Completes the open shard and writes the manifest (complete; incomplete after an I/O error).
        True when every accepted record was written."""
        if self.finalized:
            return not self.error
        self.finalized = True
        if not self.error:
            try:
                self._complete_shard()
            except OSError as e:
                self._fail(e)
        elif self._fd >= 0:
            os.close(self._fd)  # keep the .partial name: the readers report its torn tail
            self._fd = -1
        try:
            self._write_manifest("incomplete" if self.error else "complete")
        except OSError as e:
            self._fail(e)
        return not self.error

    # ---- internals ----
    def _partial_path(self) -> Path:
        assert self._current is not None
        return self.dir / (self._current.file + PARTIAL_SUFFIX)

    def _fail(self, e: OSError) -> None:
        path = e.filename or self.dir
        if not self.error:
            self.error = f"cannot write {path}: {e.strerror or e}"

    def _open_shard(self, first_seq: int) -> None:
        index = len(self._completed)
        name = f"shard_{index:06d}.qdr"
        self._current = _Shard(file=name, index=index, first_seq=first_seq)
        path = self._partial_path()
        header = ShardHeader(
            format_version=FORMAT_VERSION,
            header_size=HEADER_SIZE,
            record_size=self.record_size,
            image_width=self.config.image_width,
            image_height=self.config.image_height,
            depth_encoding=DEPTH_ENCODING_UINT16_MM,
            max_knots=self.layout[2],
            max_ctrl_pts=self.config.max_ctrl_pts,
            max_yaw_pts=self.config.max_yaw_pts,
            shard_index=index,
            camera_fx_px=self.config.camera_fx_px,
            camera_fy_px=self.config.camera_fy_px,
            camera_cx_px=self.config.camera_cx_px,
            camera_cy_px=self.config.camera_cy_px,
            layout_json=layout_json(*self.layout),
        )
        self._fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_CLOEXEC, 0o644)
        self._write_all(serialize_shard_header(header), path)
        self._current.bytes = HEADER_SIZE

    def _write_all(self, data: bytes | memoryview, path: Path) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._fd, view)
            except OSError as e:
                raise OSError(e.errno, e.strerror, str(path)) from None
            view = view[n:]

    def _complete_shard(self) -> None:
        if self._fd < 0 or self._current is None:
            return
        path = self._partial_path()
        if self.config.fsync:
            os.fsync(self._fd)
        os.close(self._fd)
        self._fd = -1
        os.replace(path, self.dir / self._current.file)
        if self.config.fsync:
            self._fsync_dir()
        self._completed.append(self._current)
        self._current = None
        self._write_manifest("incomplete")

    def _write(self, r: PlanRecordData, seq: int) -> None:
        if self._fd < 0:
            self._open_shard(seq)
        assert self._current is not None
        self._write_all(encode_record(r, seq, self.dtype), self._partial_path())
        cur = self._current
        cur.records += 1
        cur.bytes += self.record_size
        cur.last_seq = seq
        ep = self._episodes.get(int(r.episode_id))
        if ep is None:
            self._episodes[int(r.episode_id)] = _Episode(int(r.episode_id), int(r.world_seed), 1)
        else:
            ep.records += 1
        self.counts.written += 1
        if cur.records >= self.records_per_shard:
            self._complete_shard()

    def _fsync_dir(self) -> None:
        fd = os.open(self.dir, os.O_RDONLY | os.O_DIRECTORY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    def manifest_text(self, status: str) -> str:
        """The manifest as the C++ writer emits it (the same keys in the same order; yaml-cpp's layout)."""
        c = self.config
        seeds: list[int] = []
        for ep in self._episodes.values():
            if ep.world_seed not in seeds:
                seeds.append(ep.world_seed)
        lines = [
            "# quad_il cpp_data_collector dataset manifest; format: docs/data_format.md",
            "format: quad_il.cpp_data_collector",
            f"format_version: {FORMAT_VERSION}",
            f"status: {status}",
            f"created_utc: {self.created_utc}",
            f"finalized_utc: {utc_now_iso8601() if status != 'incomplete' else _quoted('')}",
            f"software_commit: {_quoted(c.software_commit)}",
            f"record_size_bytes: {self.record_size}",
            "config:",
            f"  output_dir: {_plain_or_quoted(str(self.dir))}",
            f"  shard_size_mb: {_shortest(c.shard_size_mb)}",
            f"  queue_capacity: {c.queue_capacity}",
            f"  full_queue_policy: {c.full_queue_policy}",
            f"  image_width: {c.image_width}",
            f"  image_height: {c.image_height}",
            f"  max_ctrl_pts: {c.max_ctrl_pts}",
            f"  max_yaw_pts: {c.max_yaw_pts}",
            f"  fsync: {'true' if c.fsync else 'false'}",
            f"  software_commit: {_quoted(c.software_commit)}",
            "  camera:",
            f"    fx_px: {_shortest(c.camera_fx_px)}",
            f"    fy_px: {_shortest(c.camera_fy_px)}",
            f"    cx_px: {_shortest(c.camera_cx_px)}",
            f"    cy_px: {_shortest(c.camera_cy_px)}",
        ]
        lines.append("run_info:")
        if self.run_info:
            lines += [f"  {_plain_or_quoted(k)}: {_quoted(v)}" for k, v in self.run_info.items()]
        else:
            lines.append("  {}")
        lines += [
            "counts:",
            f"  submitted: {self.counts.submitted}",
            f"  written: {self.counts.written}",
            f"  dropped: {self.counts.dropped}",
            f"  rejected: {self.counts.rejected}",
            f"  lost: {self.counts.lost}",
            "dropped_seqs: []",
            f"world_seeds: [{', '.join(str(s) for s in seeds)}]",
        ]
        lines.append("episodes:")
        if self._episodes:
            lines += [
                f"  - {{episode_id: {e.episode_id}, world_seed: {e.world_seed}, records: {e.records}}}"
                for e in self._episodes.values()
            ]
        else:
            lines.append("  []")
        lines.append("shards:")
        if self._completed:
            lines += [
                f"  - {{file: {s.file}, index: {s.index}, records: {s.records}, bytes: {s.bytes}, "
                f"first_seq: {s.first_seq}, last_seq: {s.last_seq}}}"
                for s in self._completed
            ]
        else:
            lines.append("  []")
        lines.append(f"writer_error: {_quoted(self.error)}")
        return "\n".join(lines) + "\n"

    def _write_manifest(self, status: str) -> None:
        """Atomically: a temporary file, fsynced, renamed; a failed write leaves the old manifest and no
        temporary file."""
        final = self.dir / MANIFEST_NAME
        tmp = final.with_name(MANIFEST_NAME + ".tmp")
        data = self.manifest_text(status).encode("utf-8")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
            try:
                view = memoryview(data)
                while view:
                    view = view[os.write(fd, view) :]
                if self.config.fsync:
                    os.fsync(fd)
            finally:
                os.close(fd)
            os.replace(tmp, final)
        except OSError as e:
            tmp.unlink(missing_ok=True)
            raise OSError(e.errno, e.strerror, str(tmp)) from None
        if self.config.fsync:
            self._fsync_dir()
