"""The cpp_data_collector record format, version 1, on the Python side (specification: docs/data_format.md).

This is an independent implementation of the layout: the reader builds the record dtype from its own table and
refuses shards whose header describes anything else, so a change on one side cannot go unnoticed.
"""

from __future__ import annotations

import json
import re
import struct
import zlib
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

FORMAT_VERSION = 1
SHARD_MAGIC = b"QILSHARD"
HEADER_SIZE = 4096
HEADER_FIXED_SIZE = 88
HEADER_CRC_OFFSET = 84
RECORD_MAGIC = 0x43455251  # b"QREC" little-endian
DEPTH_ENCODING_UINT16_MM = 1
STATUS_TEXT_BYTES = 48
EXTRA_KNOT_SLOTS = 8  # max_knots = max_ctrl_pts + 8 (orders up to 7)
MANIFEST_NAME = "manifest.yaml"
SHARD_NAME_RE = re.compile(r"^shard_(?P<index>\d{6})\.qdr(?P<partial>\.partial)?$")

DEPTH_CODE_INVALID = 0  # NaN
DEPTH_CODE_TOO_NEAR = 1  # -inf
DEPTH_CODE_TOO_FAR = 65535  # +inf
DEPTH_CODE_MIN_VALID = 2

# struct layout of the header's fixed part (little-endian), offsets 0..88.
_HEADER_STRUCT = struct.Struct("<8s10I4d2I")


class DatasetError(Exception):
    """Base class of every error about datasets, shards and their content."""


class NotADatasetError(DatasetError):
    """A path that is missing, not a directory, empty, or holds something else than a dataset or shard."""


class FormatVersionError(DatasetError):
    """A shard or manifest of a format version this code does not read."""


class CorruptDataError(DatasetError):
    """Damaged content: CRC mismatch, truncated completed shard, missing shard, manifest disagreement."""


class EmptyDatasetError(DatasetError):
    """A valid dataset that holds no records."""


@dataclass(frozen=True)
class ShardHeader:
    format_version: int
    header_size: int
    record_size: int
    image_width: int
    image_height: int
    depth_encoding: int
    max_knots: int
    max_ctrl_pts: int
    max_yaw_pts: int
    shard_index: int
    camera_fx_px: float
    camera_fy_px: float
    camera_cx_px: float
    camera_cy_px: float
    layout_json: str

    @property
    def layout_params(self) -> tuple[int, int, int, int, int]:
        return (self.image_width, self.image_height, self.max_knots, self.max_ctrl_pts, self.max_yaw_pts)


# The record head (312 bytes), in order: (name, numpy dtype, shape). Offsets follow from natural alignment and
# are checked against the documented ones in record_dtype().
_HEAD_FIELDS: list[tuple[str, str, tuple[int, ...]]] = [
    ("magic", "<u4", ()),
    ("flags", "<u4", ()),
    ("seq", "<u8", ()),
    ("episode_id", "<i8", ()),
    ("world_seed", "<u8", ()),
    ("sim_time_s", "<f8", ()),
    ("depth_stamp_s", "<f8", ()),
    ("odom_stamp_s", "<f8", ()),
    ("p_world_body", "<f8", (3,)),
    ("v_world", "<f8", (3,)),
    ("q_world_body", "<f8", (4,)),
    ("w_body", "<f8", (3,)),
    ("goal_world", "<f8", (3,)),
    ("bspline_start_time_s", "<f8", ()),
    ("bspline_yaw_dt_s", "<f8", ()),
    ("bspline_traj_id", "<i8", ()),
    ("bspline_order", "<i4", ()),
    ("num_knots", "<u4", ()),
    ("num_ctrl_pts", "<u4", ()),
    ("num_yaw_pts", "<u4", ()),
    ("plan_status_code", "<i4", ()),
    ("reserved", "<u4", ()),
    ("t_map_update_ms", "<f8", ()),
    ("t_frontend_ms", "<f8", ()),
    ("t_optimization_ms", "<f8", ()),
    ("t_total_ms", "<f8", ()),
    ("plan_status_text", "|S48", ()),
]
HEAD_SIZE = 312


@lru_cache(maxsize=32)
def record_layout(
    image_width: int, image_height: int, max_knots: int, max_ctrl_pts: int, max_yaw_pts: int
) -> tuple[tuple[str, str, tuple[int, ...], int], ...]:
    """Every field of a version-1 record as (name, dtype, shape, byte offset), the CRC last."""
    if image_width < 1 or image_height < 1:
        raise ValueError(f"image size {image_width}x{image_height} must be positive")
    fields: list[tuple[str, str, tuple[int, ...], int]] = []
    offset = 0
    for name, dt, shape in _HEAD_FIELDS:
        size = np.dtype(dt).itemsize * int(np.prod(shape, dtype=np.int64))
        align = np.dtype(dt).alignment
        offset = (offset + align - 1) // align * align
        fields.append((name, dt, shape, offset))
        offset += size
    if offset != HEAD_SIZE:
        raise AssertionError(f"record head is {offset} bytes, the format says {HEAD_SIZE}")
    fields.append(("knots", "<f8", (max_knots,), offset))
    offset += 8 * max_knots
    fields.append(("ctrl_pts_world", "<f8", (max_ctrl_pts, 3), offset))
    offset += 24 * max_ctrl_pts
    if max_yaw_pts > 0:
        fields.append(("yaw_pts", "<f8", (max_yaw_pts,), offset))
    offset += 8 * max_yaw_pts
    fields.append(("depth_code", "<u2", (image_height, image_width), offset))
    offset += 2 * image_width * image_height
    record_size = (offset + 4 + 7) // 8 * 8
    fields.append(("crc32", "<u4", (), record_size - 4))
    return tuple(fields)


def record_size(layout: tuple[tuple[str, str, tuple[int, ...], int], ...]) -> int:
    return layout[-1][3] + 4


@lru_cache(maxsize=32)
def record_dtype(
    image_width: int, image_height: int, max_knots: int, max_ctrl_pts: int, max_yaw_pts: int
) -> np.dtype:
    """The numpy structured dtype of one version-1 record (itemsize = record size)."""
    layout = record_layout(image_width, image_height, max_knots, max_ctrl_pts, max_yaw_pts)
    return np.dtype(
        {
            "names": [f[0] for f in layout],
            "formats": [(f[1], f[2]) if f[2] else f[1] for f in layout],
            "offsets": [f[3] for f in layout],
            "itemsize": record_size(layout),
        }
    )


def layout_json(
    image_width: int, image_height: int, max_knots: int, max_ctrl_pts: int, max_yaw_pts: int
) -> str:
    """The compact JSON layout description a version-1 header stores (byte-identical to the C++ writer's)."""
    layout = record_layout(image_width, image_height, max_knots, max_ctrl_pts, max_yaw_pts)
    fields = ",".join(
        f'["{name}","{dt}",[{",".join(str(s) for s in shape)}],{offset}]'
        for name, dt, shape, offset in layout
    )
    return f'{{"record_size":{record_size(layout)},"fields":[{fields}]}}'


def parse_shard_header(data: bytes, source: str) -> ShardHeader:
    """Parses and validates a shard header (NotADatasetError, FormatVersionError, CorruptDataError)."""
    if len(data) < HEADER_FIXED_SIZE or data[:8] != SHARD_MAGIC:
        raise NotADatasetError(
            f"{source}: not a quad_il record shard (no 'QILSHARD' magic at the start of the file)"
        )
    values = _HEADER_STRUCT.unpack_from(data, 0)
    version = values[1]
    if version != FORMAT_VERSION:
        raise FormatVersionError(
            f"{source}: record format version {version} is not supported "
            f"(this reader reads version {FORMAT_VERSION})"
        )
    if values[2] != HEADER_SIZE:
        raise CorruptDataError(f"{source}: header size {values[2]} is not {HEADER_SIZE}")
    if len(data) < HEADER_SIZE:
        raise CorruptDataError(f"{source}: truncated header ({len(data)} of {HEADER_SIZE} bytes)")
    stored_crc = values[-1]
    header = bytearray(data[:HEADER_SIZE])
    header[HEADER_CRC_OFFSET : HEADER_CRC_OFFSET + 4] = b"\0\0\0\0"
    crc = zlib.crc32(header)
    if crc != stored_crc:
        raise CorruptDataError(
            f"{source}: header CRC mismatch (stored {stored_crc}, computed {crc}): corrupted header"
        )
    json_size = values[-2]
    if json_size > HEADER_SIZE - HEADER_FIXED_SIZE:
        raise CorruptDataError(f"{source}: layout description size {json_size} is out of range")
    h = ShardHeader(
        format_version=version,
        header_size=values[2],
        record_size=values[3],
        image_width=values[4],
        image_height=values[5],
        depth_encoding=values[6],
        max_knots=values[7],
        max_ctrl_pts=values[8],
        max_yaw_pts=values[9],
        shard_index=values[10],
        camera_fx_px=values[11],
        camera_fy_px=values[12],
        camera_cx_px=values[13],
        camera_cy_px=values[14],
        layout_json=bytes(data[HEADER_FIXED_SIZE : HEADER_FIXED_SIZE + json_size]).decode("utf-8", "replace"),
    )
    if h.depth_encoding != DEPTH_ENCODING_UINT16_MM:
        raise CorruptDataError(f"{source}: unknown depth encoding {h.depth_encoding}")
    try:
        expected = layout_json(*h.layout_params)
        stored = json.loads(h.layout_json)
    except (ValueError, json.JSONDecodeError) as exc:
        raise CorruptDataError(f"{source}: bad layout description in the header: {exc}") from None
    if h.layout_json != expected or stored.get("record_size") != h.record_size:
        raise CorruptDataError(
            f"{source}: the record layout stored in the header differs from format version "
            f"{FORMAT_VERSION}'s layout for these dimensions"
        )
    return h


def serialize_shard_header(h: ShardHeader) -> bytes:
    """Header -> exactly HEADER_SIZE bytes with its CRC (used by tests to build shards of other versions)."""
    layout = h.layout_json.encode("utf-8")
    out = bytearray(HEADER_SIZE)
    _HEADER_STRUCT.pack_into(
        out,
        0,
        SHARD_MAGIC,
        h.format_version,
        h.header_size,
        h.record_size,
        h.image_width,
        h.image_height,
        h.depth_encoding,
        h.max_knots,
        h.max_ctrl_pts,
        h.max_yaw_pts,
        h.shard_index,
        h.camera_fx_px,
        h.camera_fy_px,
        h.camera_cx_px,
        h.camera_cy_px,
        len(layout),
        0,
    )
    out[HEADER_FIXED_SIZE : HEADER_FIXED_SIZE + len(layout)] = layout
    struct.pack_into("<I", out, HEADER_CRC_OFFSET, zlib.crc32(out))
    return bytes(out)


def encode_depth_m(depth_m: np.ndarray) -> np.ndarray:
    """Depth in metres (float32, REP 118 specials) -> uint16 codes, exactly as the C++ writer does.

    code = floor(float64(d) * 1000 + 0.5) clamped to [2, 65535] (exact in binary64 for unclamped values);
    NaN and d <= 0 -> 0, -inf -> 1, +inf and d >= 65.5345 m -> 65535.
    """
    d = np.asarray(depth_m, dtype=np.float32).astype(np.float64)
    with np.errstate(invalid="ignore"):
        mm = np.floor(d * 1000.0 + 0.5)
        codes = np.clip(np.nan_to_num(mm, nan=2.0, posinf=65535.0, neginf=2.0), 2.0, 65535.0).astype(
            np.uint16
        )
        codes[(d <= 0.0) | np.isnan(d)] = DEPTH_CODE_INVALID
    codes[d == -np.inf] = DEPTH_CODE_TOO_NEAR
    return codes


@lru_cache(maxsize=4)
def depth_lut(dtype: str = "float32") -> np.ndarray:
    """Code -> metres for all 65536 codes: NaN, -inf, +inf for the special codes, else dtype(code / 1000).

    The conversion goes straight from the float64 quotient to `dtype` (one rounding, to nearest even).
    """
    codes = np.arange(65536, dtype=np.float64)
    metres = codes / 1000.0
    metres[DEPTH_CODE_INVALID] = np.nan
    metres[DEPTH_CODE_TOO_NEAR] = -np.inf
    metres[DEPTH_CODE_TOO_FAR] = np.inf
    lut = metres.astype(np.dtype(dtype))
    lut.setflags(write=False)
    return lut


def decode_depth_codes(codes: np.ndarray, dtype: str = "float32") -> np.ndarray:
    """uint16 depth codes -> metres (float32 by default; "float16" for the npz's depth_m)."""
    codes = np.asarray(codes)
    if codes.dtype != np.uint16:
        raise TypeError(f"depth codes must be uint16, got {codes.dtype}")
    return depth_lut(dtype)[codes]
