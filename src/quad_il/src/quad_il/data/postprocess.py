"""Shards -> fixed-size training arrays (the `.npz` contract of docs/data_format.md, section "npz").

The expert's B-spline has a variable number of control points and its own time origin. For training it is
resampled to a fixed representation, the same for every record:

1. Sample times s_j = j * horizon_s / (M - 1), j = 0..M-1, M = 8 * (K - 3) + 1 (8 samples per knot interval).
2. The expert spline (degree p = bspline_order, knots U, control points P, n of them) is evaluated at the sim
   times t0 + s_j, t0 = depth_stamp_s (the observation's time), i.e. at the parameters
   u_j = clip(U[p] + (t0 - bspline_start_time_s) + s_j, U[p], U[n]):
   the spline is held at its start before start_time and at its end after its last knot.
3. A uniform cubic B-spline with K control points and knots tau_i = (i - 3) * dt, i = 0..K+3,
   dt = horizon_s / (K - 3) (domain [0, horizon_s]) is fitted to those samples by least squares:
   X = pinv(A) @ Y with A[j, i] = N_i(s_j).
4. bspline_ctrl_local = R_z(yaw)^T (X - p_world_body), yaw = the heading of q_world_body: the yaw-only
   vehicle frame centred at the vehicle.

`records_to_arrays` does this for any structured record array (a shard's memory map or load_dataset's copy),
so training can read shards directly with exactly the resampling the npz holds.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from quad_il.data.bspline import basis_matrix, de_boor, fit_matrix, uniform_knots
from quad_il.data.format import FORMAT_VERSION, DatasetError, EmptyDatasetError, FormatVersionError, depth_lut
from quad_il.data.shards import LoadedRecords, OnCorrupt, open_dataset
from quad_il.tools.cli import HelpFormatter

log = logging.getLogger(__name__)

DEFAULT_NUM_CTRL_PTS = 10
DEFAULT_HORIZON_S = 2.0
SAMPLES_PER_INTERVAL = 8
FIT_DEGREE = 3
_CHUNK = 1024  # records per vectorised de Boor pass (bounds temporary memory)


class ResampleConfig(BaseModel):
    """The fixed B-spline representation: K control points over horizon_s seconds from the depth stamp."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    num_ctrl_pts: int = Field(DEFAULT_NUM_CTRL_PTS, ge=FIT_DEGREE + 1, le=1000)
    horizon_s: float = Field(DEFAULT_HORIZON_S, gt=0.0, le=1000.0, allow_inf_nan=False)

    @property
    def knot_dt_s(self) -> float:
        return self.horizon_s / (self.num_ctrl_pts - FIT_DEGREE)

    @property
    def sample_times_s(self) -> np.ndarray:
        m = SAMPLES_PER_INTERVAL * (self.num_ctrl_pts - FIT_DEGREE) + 1
        return np.linspace(0.0, self.horizon_s, m)


# The npz contract: name -> (dtype, per-record shape; "K" = num_ctrl_pts, "H"/"W" = image size).
NPZ_ARRAYS: dict[str, tuple[str, tuple[str | int, ...]]] = {
    "depth_m": ("float16", ("H", "W")),
    "episode_id": ("int64", ()),
    "world_seed": ("uint64", ()),
    "sim_time_s": ("float64", ()),
    "depth_stamp_s": ("float64", ()),
    "odom_stamp_s": ("float64", ()),
    "p_world_body": ("float32", (3,)),
    "v_world": ("float32", (3,)),
    "q_world_body": ("float32", (4,)),
    "w_body": ("float32", (3,)),
    "goal_world": ("float32", (3,)),
    "bspline_ctrl_world": ("float32", ("K", 3)),
    "bspline_ctrl_local": ("float32", ("K", 3)),
    # Extras beyond the learning stack's contract.
    "record_seq": ("uint64", ()),
    "plan_status_code": ("int32", ()),
    "fit_rms_m": ("float32", ()),
}
NPZ_SCALARS = ("num_ctrl_pts", "horizon_s", "format_version")


@dataclass(frozen=True)
class FixedSizeArrays:
    """Fixed-size arrays of N records (the npz contract). Shapes and dtypes are checked when built."""

    depth_m: np.ndarray
    episode_id: np.ndarray
    world_seed: np.ndarray
    sim_time_s: np.ndarray
    depth_stamp_s: np.ndarray
    odom_stamp_s: np.ndarray
    p_world_body: np.ndarray
    v_world: np.ndarray
    q_world_body: np.ndarray
    w_body: np.ndarray
    goal_world: np.ndarray
    bspline_ctrl_world: np.ndarray
    bspline_ctrl_local: np.ndarray
    record_seq: np.ndarray
    plan_status_code: np.ndarray
    fit_rms_m: np.ndarray
    num_ctrl_pts: int = DEFAULT_NUM_CTRL_PTS
    horizon_s: float = DEFAULT_HORIZON_S
    format_version: int = FORMAT_VERSION

    def __post_init__(self) -> None:
        n = self.episode_id.shape[0] if self.episode_id.ndim == 1 else -1
        if self.depth_m.ndim != 3:
            raise ValueError(f"depth_m must be (N, H, W), got shape {self.depth_m.shape}")
        dims = {"K": self.num_ctrl_pts, "H": self.depth_m.shape[1], "W": self.depth_m.shape[2]}
        for name, (dtype, shape) in NPZ_ARRAYS.items():
            arr = getattr(self, name)
            want = (n, *(dims[s] if isinstance(s, str) else s for s in shape))
            if arr.dtype != np.dtype(dtype) or arr.shape != want:
                raise ValueError(f"{name}: expected {dtype} {want}, got {arr.dtype} {arr.shape}")

    def __len__(self) -> int:
        return int(self.episode_id.shape[0])

    def save(
        self,
        path: str | os.PathLike[str],
        *,
        compress: bool = False,
        extra: Mapping[str, np.ndarray] | None = None,
    ) -> Path:
        """Writes the arrays and scalars to `path` (must end in .npz); `extra`: further per-record arrays of
        other writers (e.g. `il_partition` of quad_il.imitation.convert), never replacing a contract key."""
        path = Path(path)
        if path.suffix != ".npz":
            raise ValueError(f"{path}: output file name must end in .npz")
        arrays = {name: getattr(self, name) for name in NPZ_ARRAYS}
        for name, value in (extra or {}).items():
            if name in arrays or name in NPZ_SCALARS:
                raise ValueError(f"extra array {name!r} would replace a key of the npz contract")
            if len(value) != len(self):
                raise ValueError(f"extra array {name!r} has {len(value)} rows, the records are {len(self)}")
            arrays[name] = value
        arrays["num_ctrl_pts"] = np.asarray(self.num_ctrl_pts, dtype=np.int64)
        arrays["horizon_s"] = np.asarray(self.horizon_s, dtype=np.float64)
        arrays["format_version"] = np.asarray(self.format_version, dtype=np.int64)
        (np.savez_compressed if compress else np.savez)(path, **arrays)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> FixedSizeArrays:
        """Reads and validates an npz written by save(); clear errors for foreign files and other versions."""
        path = Path(path)
        if not path.is_file():
            raise DatasetError(f"{path}: no such npz file")
        try:
            data = np.load(path, allow_pickle=False)
        except (OSError, ValueError) as exc:
            raise DatasetError(f"{path}: not an npz file: {exc}") from None
        with data:
            missing = [k for k in (*NPZ_ARRAYS, *NPZ_SCALARS) if k not in data.files]
            if "format_version" not in data.files:
                raise DatasetError(f"{path}: not a quad_il training npz (no 'format_version' array)")
            version = int(data["format_version"])
            if version != FORMAT_VERSION:
                raise FormatVersionError(
                    f"{path}: npz format version {version} is not supported "
                    f"(this code reads version {FORMAT_VERSION})"
                )
            if missing:
                raise DatasetError(
                    f"{path}: not a quad_il training npz (missing arrays: {', '.join(missing)})"
                )
            kwargs = {name: data[name] for name in NPZ_ARRAYS}
            return cls(
                **kwargs,
                num_ctrl_pts=int(data["num_ctrl_pts"]),
                horizon_s=float(data["horizon_s"]),
                format_version=version,
            )

    def equals(self, other: FixedSizeArrays) -> bool:
        """Bit-for-bit equality of every array and scalar (NaN equal to NaN)."""
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray):
                if a.dtype != b.dtype or a.shape != b.shape or a.tobytes() != b.tobytes():
                    return False
            elif a != b:
                return False
        return True


def yaw_from_quaternion_xyzw(q: np.ndarray) -> np.ndarray:
    """Heading (rotation about world z, radians) of quaternions (..., 4) stored x, y, z, w."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def world_to_local(points_world: np.ndarray, p_world_body: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """(N, K, 3) world points -> the yaw-only vehicle frame centred at p_world_body: R_z(yaw)^T (P - p)."""
    d = points_world - p_world_body[:, None, :]
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], axis=-1)


def local_to_world(points_local: np.ndarray, p_world_body: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Inverse of world_to_local: p + R_z(yaw) L."""
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    x, y = points_local[..., 0], points_local[..., 1]
    rotated = np.stack([c * x - s * y, s * x + c * y, points_local[..., 2]], axis=-1)
    return rotated + p_world_body[:, None, :]


def expert_samples(records: np.ndarray, sample_times_s: np.ndarray) -> np.ndarray:
    """(N, M, 3): each record's expert spline at t0 + s_j (held at its ends), t0 = depth_stamp_s."""
    n = len(records)
    out = np.empty((n, len(sample_times_s), 3), dtype=np.float64)
    orders = records["bspline_order"].astype(np.int64)
    for p in np.unique(orders):
        for start in range(0, n, _CHUNK):
            sel = np.nonzero(orders[start : start + _CHUNK] == p)[0] + start
            if sel.size == 0:
                continue
            rec = records[sel]
            knots = np.asarray(rec["knots"], dtype=np.float64)
            num_ctrl = np.asarray(rec["num_ctrl_pts"], dtype=np.int64)
            lo = knots[:, p]
            hi = np.take_along_axis(knots, num_ctrl[:, None], axis=1)[:, 0]
            offset = np.asarray(rec["depth_stamp_s"], dtype=np.float64) - rec["bspline_start_time_s"]
            u = lo[:, None] + offset[:, None] + sample_times_s[None, :]
            u = np.clip(u, lo[:, None], hi[:, None])
            out[sel] = de_boor(knots, np.asarray(rec["ctrl_pts_world"]), num_ctrl, int(p), u)
    return out


def records_to_arrays(
    records: np.ndarray | np.void | LoadedRecords,
    *,
    num_ctrl_pts: int = DEFAULT_NUM_CTRL_PTS,
    horizon_s: float = DEFAULT_HORIZON_S,
) -> FixedSizeArrays:
    """Shard records (a ShardReader's view, a slice, one record, LoadedRecords) -> the npz contract arrays."""
    if isinstance(records, LoadedRecords):
        records = records.records
    if isinstance(records, np.void):  # one record, e.g. dataset[i]
        records = np.atleast_1d(records)
    if records.dtype.names is None or "depth_code" not in records.dtype.names:
        raise TypeError("records must be a structured array of shard records (quad_il.data.shards)")
    config = ResampleConfig(num_ctrl_pts=num_ctrl_pts, horizon_s=horizon_s)
    s = config.sample_times_s
    fit = fit_matrix(config.num_ctrl_pts, FIT_DEGREE, config.knot_dt_s, s)  # (K, M) = pinv(A)
    basis = basis_matrix(
        uniform_knots(config.num_ctrl_pts, FIT_DEGREE, config.knot_dt_s), config.num_ctrl_pts, FIT_DEGREE, s
    )  # (M, K) = A, for the fit residual
    y = expert_samples(records, s)  # (N, M, 3)
    ctrl_world = np.einsum("km,nmd->nkd", fit, y)
    resid = np.einsum("mk,nkd->nmd", basis, ctrl_world) - y
    rms = np.sqrt(np.mean(np.sum(resid * resid, axis=-1), axis=-1))
    p = np.asarray(records["p_world_body"], dtype=np.float64)
    q = np.asarray(records["q_world_body"], dtype=np.float64)
    ctrl_local = world_to_local(ctrl_world, p, yaw_from_quaternion_xyzw(q))
    f32 = np.float32
    return FixedSizeArrays(
        depth_m=depth_lut("float16")[records["depth_code"]],
        episode_id=np.asarray(records["episode_id"], dtype=np.int64),
        world_seed=np.asarray(records["world_seed"], dtype=np.uint64),
        sim_time_s=np.asarray(records["sim_time_s"], dtype=np.float64),
        depth_stamp_s=np.asarray(records["depth_stamp_s"], dtype=np.float64),
        odom_stamp_s=np.asarray(records["odom_stamp_s"], dtype=np.float64),
        p_world_body=p.astype(f32),
        v_world=np.asarray(records["v_world"]).astype(f32),
        q_world_body=q.astype(f32),
        w_body=np.asarray(records["w_body"]).astype(f32),
        goal_world=np.asarray(records["goal_world"]).astype(f32),
        bspline_ctrl_world=ctrl_world.astype(f32),
        bspline_ctrl_local=ctrl_local.astype(f32),
        record_seq=np.asarray(records["seq"], dtype=np.uint64),
        plan_status_code=np.asarray(records["plan_status_code"], dtype=np.int32),
        fit_rms_m=rms.astype(f32),
        num_ctrl_pts=config.num_ctrl_pts,
        horizon_s=config.horizon_s,
        format_version=FORMAT_VERSION,
    )


def concatenate(parts: Sequence[FixedSizeArrays]) -> FixedSizeArrays:
    """Joins arrays of the same representation (K, horizon, version, image size)."""
    if not parts:
        raise ValueError("nothing to concatenate")
    first = parts[0]
    for other in parts[1:]:
        if (other.num_ctrl_pts, other.horizon_s, other.format_version) != (
            first.num_ctrl_pts,
            first.horizon_s,
            first.format_version,
        ):
            raise ValueError(
                "cannot concatenate arrays with different num_ctrl_pts, horizon_s or format_version"
            )
    joined = {name: np.concatenate([getattr(p, name) for p in parts]) for name in NPZ_ARRAYS}
    return FixedSizeArrays(
        **joined,
        num_ctrl_pts=first.num_ctrl_pts,
        horizon_s=first.horizon_s,
        format_version=first.format_version,
    )


def iter_shard_arrays(
    in_dir: str | os.PathLike[str],
    *,
    num_ctrl_pts: int = DEFAULT_NUM_CTRL_PTS,
    horizon_s: float = DEFAULT_HORIZON_S,
    on_corrupt: OnCorrupt = "raise",
) -> Iterator[tuple[str, FixedSizeArrays]]:
    """(shard file name, its valid records' arrays) for every shard of one dataset that holds valid records,
    in order: the parts postprocess_datasets concatenates, one at a time (a reader that reduces each part, as
    training's loader does, holds one shard's full-resolution depth instead of the dataset's)."""
    for shard, records, _indices in open_dataset(in_dir).valid_record_arrays(on_corrupt=on_corrupt):
        if len(records):
            yield shard.path.name, records_to_arrays(records, num_ctrl_pts=num_ctrl_pts, horizon_s=horizon_s)


def postprocess_datasets(
    in_dirs: Sequence[str | os.PathLike[str]],
    *,
    num_ctrl_pts: int = DEFAULT_NUM_CTRL_PTS,
    horizon_s: float = DEFAULT_HORIZON_S,
    on_corrupt: OnCorrupt = "raise",
    progress: bool = False,
) -> FixedSizeArrays:
    """Every valid record of the datasets (in order) -> FixedSizeArrays, one shard at a time from the maps."""
    from tqdm import tqdm

    if not in_dirs:
        raise DatasetError("no input dataset directory given")
    datasets = [open_dataset(d) for d in in_dirs]
    layouts = {ds.header.layout_params for ds in datasets if ds.header is not None}
    if len(layouts) > 1:
        raise DatasetError(f"input datasets differ in record layout (image size, maxima): {sorted(layouts)}")
    parts: list[FixedSizeArrays] = []
    shards = sum(len(ds.shards) for ds in datasets)
    with tqdm(total=shards, desc="shards", unit="shard", disable=not progress, file=sys.stderr) as bar:
        for ds in datasets:
            for _shard, records, _indices in ds.valid_record_arrays(on_corrupt=on_corrupt):
                if len(records):
                    parts.append(records_to_arrays(records, num_ctrl_pts=num_ctrl_pts, horizon_s=horizon_s))
                bar.update(1)
    if not parts:
        raise EmptyDatasetError(f"{', '.join(str(d) for d in in_dirs)}: dataset holds no records")
    return parts[0] if len(parts) == 1 else concatenate(parts)


def main(argv: Sequence[str] | None = None) -> int:
    """CLI of training_only/cpp_dataset_postprocessing.py."""
    ap = argparse.ArgumentParser(
        formatter_class=HelpFormatter,
        prog="cpp_dataset_postprocessing.py",
        description="Convert cpp_data_collector shards to an .npz of fixed-size arrays (docs/data_format.md)",
    )
    ap.add_argument(
        "in_dirs", nargs="+", metavar="IN_DIR", help="dataset directory (several are concatenated)"
    )
    ap.add_argument("out", metavar="OUT.npz", help="output file")
    ap.add_argument(
        "--num-ctrl-pts",
        type=int,
        default=DEFAULT_NUM_CTRL_PTS,
        help="K, control points of the resampled B-spline",
    )
    ap.add_argument(
        "--horizon-s", type=float, default=DEFAULT_HORIZON_S, help="time span of the resampled B-spline (s)"
    )
    ap.add_argument(
        "--on-corrupt",
        choices=["raise", "skip"],
        default="raise",
        help="what to do with records failing CRC or torn completed shards",
    )
    ap.add_argument("--compress", action="store_true", help="np.savez_compressed (smaller, slower to load)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(message)s")
    try:
        config = ResampleConfig(num_ctrl_pts=args.num_ctrl_pts, horizon_s=args.horizon_s)
        out = Path(args.out)
        if out.suffix != ".npz":
            raise DatasetError(f"{out}: output file name must end in .npz")
        if not out.parent.is_dir():
            raise DatasetError(f"{out.parent}: output directory does not exist")
        arrays = postprocess_datasets(
            args.in_dirs,
            num_ctrl_pts=config.num_ctrl_pts,
            horizon_s=config.horizon_s,
            on_corrupt=args.on_corrupt,
            progress=not args.quiet,
        )
        arrays.save(out, compress=args.compress)
    except (DatasetError, ValueError) as exc:
        print(f"cpp_dataset_postprocessing: error: {exc}", file=sys.stderr)
        return 1
    print(
        f"wrote {out}: {len(arrays)} samples, depth {arrays.depth_m.shape[1]}x{arrays.depth_m.shape[2]}, "
        f"K={arrays.num_ctrl_pts}, horizon {arrays.horizon_s} s, "
        f"max fit rms {float(arrays.fit_rms_m.max()):.4f} m",
        file=sys.stderr,
    )
    return 0
