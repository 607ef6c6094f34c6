"""Demonstration datasets for training: validation, one-off preprocessing, split by episode, fast batching.

Input: the collector's `.npz` files (`cpp_dataset_postprocessing.py`, issue 6) or directories of them, or
shard directories (read with quad_il.data's postprocessing, so exactly as the `.npz` would hold them). Every
file is validated (format version, keys, shapes, finite values) and its depth images are preprocessed once
with the policy's own `DepthPreprocessor` into a float16 tensor at the network's input size, so an epoch is
pure tensor indexing (no per-sample Python work). Uncompressed `.npz` members are memory-mapped, so a dataset
larger than RAM at camera resolution can still be prepared.

Contract of an `.npz` (arrays over N records; K control points):
    depth_m float16 (N,H,W) metres (REP 118: +inf no return, -inf too near, NaN invalid),
    episode_id int64 (N,), world_seed uint64 (N,),
    sim_time_s, depth_stamp_s, odom_stamp_s float64 (N,), p_world_body, v_world, w_body, goal_world float32
    (N,3), q_world_body float32 (N,4) xyzw, bspline_ctrl_world, bspline_ctrl_local float32 (N,K,3);
    scalars num_ctrl_pts (K), horizon_s, format_version.
"""

from __future__ import annotations

import collections
import concurrent.futures
import hashlib
import math
import zipfile
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import Tensor

from quad_il.data import FORMAT_VERSION as COLLECTOR_FORMAT_VERSION
from quad_il.data.partitions import IL_PARTITION_KEY, PARTITION_CODES, Partition
from quad_il.learning.preprocessing import DepthPreprocessor, world_to_local_points, yaw_from_quaternion

# Versions of the collector's npz layout this code reads (quad_il.data, docs/data_format.md).
SUPPORTED_FORMAT_VERSIONS: tuple[int, ...] = (COLLECTOR_FORMAT_VERSION,)
# Tolerance of the check that the file's bspline_ctrl_local equals our own world->local transform (float32
# data).
LOCAL_FRAME_TOL_M = 1e-3
_PREPARE_CHUNK = 32  # images per preprocessing pass: small enough to stay in cache

_VECTOR_FIELDS: dict[str, tuple[int, ...]] = {
    "p_world_body": (3,),
    "v_world": (3,),
    "q_world_body": (4,),
    "w_body": (3,),
    "goal_world": (3,),
}
_TIME_FIELDS = ("sim_time_s", "depth_stamp_s", "odom_stamp_s")
REQUIRED_KEYS = (
    ("depth_m", "episode_id", "world_seed")
    + _TIME_FIELDS
    + tuple(_VECTOR_FIELDS)
    + ("bspline_ctrl_world", "bspline_ctrl_local", "num_ctrl_pts", "horizon_s", "format_version")
)


class DatasetError(ValueError):
    """A dataset is missing, of another format version, empty, inconsistent or holds non-finite values."""


@dataclass(frozen=True)
class SourceInfo:
    path: str
    num_samples: int
    depth_height: int
    depth_width: int
    format_version: int


@dataclass
class PreparedData:
    """All samples of one or more sources, preprocessed; tensors indexed by sample."""

    depth_x: Tensor  # (N, 1, h, w) float16, the DepthPreprocessor output
    p_world_body: Tensor  # (N, 3) float32
    v_world: Tensor
    q_world_body: Tensor  # (N, 4) xyzw
    goal_world: Tensor
    ctrl_world: Tensor  # (N, K, 3) float32
    ctrl_local: Tensor
    episode_id: NDArray[np.int64]
    world_seed: NDArray[np.uint64]
    sim_time_s: NDArray[np.float64]
    num_ctrl_pts: int
    horizon_s: float
    format_version: int
    sources: list[SourceInfo] = field(default_factory=list)
    # Per-sample PARTITION_CODES (quad_il.imitation.types) from the npz array `il_partition`; None when no
    # source has it (every row DEMO). Only the EIL loss reads it.
    partition: NDArray[np.int32] | None = None

    def __len__(self) -> int:
        return int(self.depth_x.shape[0])

    def describe(self, index: int) -> str:
        seed, episode = int(self.world_seed[index]), int(self.episode_id[index])
        return f"sample {index} (world_seed {seed}, episode {episode})"


# ------------------------------------------------------------------------------------------------ file access
def _npz_member_memmap(path: Path, zf: zipfile.ZipFile, name: str) -> np.ndarray | None:
    """Memory-map an uncompressed `.npy` member of an `.npz`; None if compressed (then read normally)."""
    info = zf.getinfo(name)
    if info.compress_type != zipfile.ZIP_STORED:
        return None
    with open(path, "rb") as f:
        f.seek(info.header_offset)
        local = f.read(30)
        if local[:4] != b"PK\x03\x04":
            return None
        name_len = int.from_bytes(local[26:28], "little")
        extra_len = int.from_bytes(local[28:30], "little")
        f.seek(info.header_offset + 30 + name_len + extra_len)
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
        if dtype.hasobject:
            return None
        offset = f.tell()
    return np.memmap(path, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran else "C")


def read_npz(path: str | Path) -> dict[str, np.ndarray]:
    """All arrays of an `.npz`; `depth_m` memory-mapped when stored uncompressed."""
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"dataset file not found: {p}")
    try:
        with zipfile.ZipFile(p) as zf:
            names = [n[:-4] for n in zf.namelist() if n.endswith(".npy")]
            depth = _npz_member_memmap(p, zf, "depth_m.npy") if "depth_m" in names else None
        with np.load(p, allow_pickle=False) as npz:
            out = {k: npz[k] for k in names if not (k == "depth_m" and depth is not None)}
    except (zipfile.BadZipFile, OSError, ValueError) as e:
        raise DatasetError(f"{p}: not a readable .npz file ({e})") from None
    if depth is not None:
        out["depth_m"] = depth
    return out


@dataclass(frozen=True)
class ShardOptions:
    """How shard directories become the npz contract (quad_il.data's postprocessing, the code of
    cpp_dataset_postprocessing.py): the fixed B-spline representation and what to do with corrupt records."""

    num_ctrl_pts: int = 10
    horizon_s: float = 2.0
    on_corrupt: str = "raise"  # raise | skip


DEFAULT_SHARD_OPTIONS = ShardOptions()


def shard_dir_arrays(path: Path, options: ShardOptions = DEFAULT_SHARD_OPTIONS) -> dict[str, np.ndarray]:
    """Arrays of a shard directory, resampled exactly as the npz postprocessing does (quad_il.data)."""
    from quad_il.data import DatasetError as CollectorDatasetError
    from quad_il.data.postprocess import postprocess_datasets

    try:
        fixed = postprocess_datasets(
            [path],
            num_ctrl_pts=options.num_ctrl_pts,
            horizon_s=options.horizon_s,
            on_corrupt=options.on_corrupt,  # type: ignore[arg-type]
        )
    except (CollectorDatasetError, ValueError) as e:
        raise DatasetError(f"{path}: cannot read as a shard dataset: {e}") from None
    return _npz_arrays(fixed)


def _npz_arrays(fixed: Any) -> dict[str, Any]:
    """quad_il.data.postprocess.FixedSizeArrays as the .npz's arrays, which prepare_arrays reads."""
    from quad_il.data.postprocess import NPZ_ARRAYS

    out: dict[str, Any] = {name: getattr(fixed, name) for name in NPZ_ARRAYS}
    out["num_ctrl_pts"] = np.int64(fixed.num_ctrl_pts)
    out["horizon_s"] = np.float64(fixed.horizon_s)
    out["format_version"] = np.int64(fixed.format_version)
    return out


def read_source(path: Path, kind: str, shards: ShardOptions = DEFAULT_SHARD_OPTIONS) -> dict[str, np.ndarray]:
    """Arrays of one source from `expand_paths`."""
    return read_npz(path) if kind == "npz" else shard_dir_arrays(path, shards)


def expand_paths(paths: Sequence[str | Path]) -> list[tuple[Path, str]]:
    """Each given path -> [(path, kind)] with kind 'npz' or 'shards'. Directories are searched for *.npz; a
    directory that is no dataset itself but holds dataset directories (a parallel collection) gives each."""
    if not paths:
        raise DatasetError("no dataset given (data.paths is empty)")
    out: list[tuple[Path, str]] = []
    for raw in paths:
        p = Path(raw)
        if p.is_file():
            if p.suffix != ".npz":
                raise DatasetError(f"{p}: expected an .npz file or a dataset directory")
            out.append((p, "npz"))
        elif p.is_dir():
            files = sorted(p.glob("*.npz"))
            subsets = sorted(d for d in p.iterdir() if d.is_dir() and (d / "manifest.yaml").is_file())
            if files:
                out += [(f, "npz") for f in files]
            elif not (p / "manifest.yaml").exists() and not any(p.glob("shard_*")) and subsets:
                # A collection of datasets (quad_il.collection.parallel: worker_0/, worker_1/, ...).
                out += [(d, "shards") for d in subsets]
            else:
                out.append((p, "shards"))
        else:
            raise DatasetError(f"dataset path does not exist: {p}")
    return out


# ------------------------------------------------------------------------------------------------- validation
def _scalar(arrays: Mapping[str, Any], key: str, source: str) -> float:
    v = np.asarray(arrays[key])
    if v.size != 1:
        raise DatasetError(f"{source}: '{key}' must be a scalar, got shape {v.shape}")
    return v.reshape(()).item()


def _first_bad_record(bad_rows: NDArray[np.bool_]) -> int:
    return int(np.flatnonzero(bad_rows)[0])


def validate_arrays(arrays: Mapping[str, Any], source: str) -> tuple[int, int, float, int]:
    """Check keys, version, shapes, finiteness (depth: while preprocessing); -> (N, K, horizon, version)."""
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if "format_version" in arrays:
        version = _scalar(arrays, "format_version", source)
        if int(version) != version or int(version) not in SUPPORTED_FORMAT_VERSIONS:
            raise DatasetError(
                f"{source}: dataset format_version {version} is not supported "
                f"(this code reads {list(SUPPORTED_FORMAT_VERSIONS)})"
            )
    if missing:
        raise DatasetError(f"{source}: not a quad_il dataset, missing keys {missing}")
    version = int(_scalar(arrays, "format_version", source))
    k = _scalar(arrays, "num_ctrl_pts", source)
    horizon_s = float(_scalar(arrays, "horizon_s", source))
    if int(k) != k or k < 2:
        raise DatasetError(f"{source}: num_ctrl_pts must be an integer >= 2, got {k}")
    k = int(k)
    if not (math.isfinite(horizon_s) and horizon_s > 0):
        raise DatasetError(f"{source}: horizon_s must be finite and > 0, got {horizon_s}")
    depth = arrays["depth_m"]
    if depth.ndim != 3:
        raise DatasetError(f"{source}: depth_m must be (N, H, W), got shape {depth.shape}")
    n = depth.shape[0]
    if n == 0:
        raise DatasetError(f"{source}: dataset is empty (0 records)")
    expected: dict[str, tuple[int, ...]] = {
        "episode_id": (n,),
        "world_seed": (n,),
        **{t: (n,) for t in _TIME_FIELDS},
        **{f: (n, *s) for f, s in _VECTOR_FIELDS.items()},
        "bspline_ctrl_world": (n, k, 3),
        "bspline_ctrl_local": (n, k, 3),
    }
    for key, shape in expected.items():
        if tuple(arrays[key].shape) != shape:
            raise DatasetError(f"{source}: '{key}' has shape {tuple(arrays[key].shape)}, expected {shape}")
    for key in ("episode_id", "world_seed"):
        if not np.issubdtype(arrays[key].dtype, np.integer):
            raise DatasetError(f"{source}: '{key}' must be integer, got {arrays[key].dtype}")
    for key in (*_TIME_FIELDS, *_VECTOR_FIELDS, "bspline_ctrl_world", "bspline_ctrl_local"):
        a = np.asarray(arrays[key])
        if not np.issubdtype(a.dtype, np.floating):
            raise DatasetError(f"{source}: '{key}' must be floating point, got {a.dtype}")
        bad = ~np.isfinite(a.reshape(n, -1)).all(axis=1)
        if bad.any():
            i = _first_bad_record(bad)
            raise DatasetError(
                f"{source}: NaN/Inf in '{key}' of record {i} (episode {int(arrays['episode_id'][i])}); "
                f"{int(bad.sum())} record(s) affected"
            )
    qn = np.linalg.norm(np.asarray(arrays["q_world_body"], dtype=np.float64), axis=1)
    bad = np.abs(qn - 1.0) > 1e-3
    if bad.any():
        i = _first_bad_record(bad)
        raise DatasetError(
            f"{source}: q_world_body of record {i} is not a unit quaternion (norm {qn[i]:.6f})"
        )
    return n, k, horizon_s, version


# ------------------------------------------------------------------------------------------------ preparation
def _negative_finite_rows(chunk: np.ndarray) -> NDArray[np.bool_]:
    """Per image: does it hold a finite negative depth? REP 118 specials (NaN invalid, -inf too near, +inf no
    return) are valid. float16 is checked on its bits (sign set, exponent not all ones, not -0): one pass."""
    flat = chunk.reshape(len(chunk), -1)
    if flat.dtype == np.float16:
        bits = flat.view(np.uint16)
        return ((bits > 0x8000) & (bits < 0xFC00)).any(axis=1)
    with np.errstate(invalid="ignore"):
        return ((flat < 0) & (flat > -np.inf)).any(axis=1)


def prepare_arrays(
    arrays: Mapping[str, Any], preprocessor: DepthPreprocessor, source: str
) -> tuple[PreparedData, SourceInfo]:
    n, k, horizon_s, version = validate_arrays(arrays, source)
    depth = arrays["depth_m"]
    if not np.issubdtype(depth.dtype, np.floating):
        raise DatasetError(f"{source}: depth_m must be floating point metres, got {depth.dtype}")
    depth_x = torch.empty((n, 1, preprocessor.out_height, preprocessor.out_width), dtype=torch.float16)
    episode_id = np.asarray(arrays["episode_id"], dtype=np.int64)
    with torch.no_grad():
        for start in range(0, n, _PREPARE_CHUNK):
            chunk = np.array(
                depth[start : start + _PREPARE_CHUNK]
            )  # a writable copy (the source may be a map)
            bad = _negative_finite_rows(chunk)
            if bad.any():
                i = start + _first_bad_record(bad)
                raise DatasetError(
                    f"{source}: negative depth in 'depth_m' of record {i} (episode {int(episode_id[i])}); "
                    "depth is >= 0 metres or a REP 118 special (NaN, -inf, +inf)"
                )
            # The preprocessor converts float16 to float32 itself (exactly), one pass fewer than numpy would.
            depth_x[start : start + len(chunk)] = preprocessor(torch.from_numpy(chunk)).to(torch.float16)
    p = torch.from_numpy(np.asarray(arrays["p_world_body"], dtype=np.float32).copy())
    q = torch.from_numpy(np.asarray(arrays["q_world_body"], dtype=np.float32).copy())
    ctrl_world = torch.from_numpy(np.asarray(arrays["bspline_ctrl_world"], dtype=np.float32).copy())
    ctrl_local_file = torch.from_numpy(np.asarray(arrays["bspline_ctrl_local"], dtype=np.float32).copy())
    ctrl_local = world_to_local_points(
        ctrl_world.double(), p.double(), yaw_from_quaternion(q.double())
    ).float()
    err = (ctrl_local - ctrl_local_file).abs().amax(dim=(1, 2))
    scale = 1.0 + ctrl_local_file.abs().amax(dim=(1, 2))
    bad_frame = err > LOCAL_FRAME_TOL_M * scale
    if bool(bad_frame.any()):
        i = int(torch.nonzero(bad_frame)[0, 0])
        raise DatasetError(
            f"{source}: bspline_ctrl_local of record {i} differs by {float(err[i]):.4g} m from the yaw-only "
            "vehicle frame of bspline_ctrl_world (docs/learning.md, Frames): the dataset's frame convention "
            "differs"
        )
    info = SourceInfo(str(source), n, int(depth.shape[1]), int(depth.shape[2]), version)
    partition = None
    if IL_PARTITION_KEY in arrays:
        partition = np.asarray(arrays[IL_PARTITION_KEY])
        if partition.shape != (n,) or not np.issubdtype(partition.dtype, np.integer):
            raise DatasetError(
                f"{source}: {IL_PARTITION_KEY} must be ({n},) integers, "
                f"got {partition.dtype} {partition.shape}"
            )
        unknown = ~np.isin(partition, list(PARTITION_CODES.values()))
        if unknown.any():
            i = int(np.flatnonzero(unknown)[0])
            raise DatasetError(
                f"{source}: {IL_PARTITION_KEY} of record {i} is {int(partition[i])}, not a partition code "
                f"{sorted(PARTITION_CODES.values())}"
            )
        partition = partition.astype(np.int32)
    data = PreparedData(
        depth_x=depth_x,
        p_world_body=p,
        v_world=torch.from_numpy(np.asarray(arrays["v_world"], dtype=np.float32).copy()),
        q_world_body=q,
        goal_world=torch.from_numpy(np.asarray(arrays["goal_world"], dtype=np.float32).copy()),
        ctrl_world=ctrl_world,
        ctrl_local=ctrl_local,
        episode_id=episode_id,
        world_seed=np.asarray(arrays["world_seed"]).astype(np.uint64),
        sim_time_s=np.asarray(arrays["sim_time_s"], dtype=np.float64),
        num_ctrl_pts=k,
        horizon_s=horizon_s,
        format_version=version,
        sources=[info],
        partition=partition,
    )
    return data, info


def concatenate(parts: Sequence[PreparedData]) -> PreparedData:
    if not parts:
        raise DatasetError("no data to concatenate")
    first = parts[0]
    for part in parts[1:]:
        if part.num_ctrl_pts != first.num_ctrl_pts or part.horizon_s != first.horizon_s:
            raise DatasetError(
                f"sources disagree on the B-spline layout: {part.sources[0].path} has K={part.num_ctrl_pts}, "
                f"horizon {part.horizon_s} s; {first.sources[0].path} has K={first.num_ctrl_pts}, "
                f"horizon {first.horizon_s} s"
            )
    if len(parts) == 1:
        return first

    def cat(name: str) -> Tensor:
        return torch.cat([getattr(p, name) for p in parts])

    def npcat(name: str) -> np.ndarray:
        return np.concatenate([getattr(p, name) for p in parts])

    return PreparedData(
        depth_x=cat("depth_x"),
        p_world_body=cat("p_world_body"),
        v_world=cat("v_world"),
        q_world_body=cat("q_world_body"),
        goal_world=cat("goal_world"),
        ctrl_world=cat("ctrl_world"),
        ctrl_local=cat("ctrl_local"),
        episode_id=npcat("episode_id"),
        world_seed=npcat("world_seed"),
        sim_time_s=npcat("sim_time_s"),
        num_ctrl_pts=first.num_ctrl_pts,
        horizon_s=first.horizon_s,
        format_version=first.format_version,
        sources=[s for p in parts for s in p.sources],
        partition=(
            None
            if all(p.partition is None for p in parts)
            else np.concatenate(
                [
                    p.partition
                    if p.partition is not None
                    else np.full(len(p), PARTITION_CODES[Partition.DEMO], dtype=np.int32)
                    for p in parts
                ]
            )
        ),
    )


def _check_depth_size(depth: Any, source: str, preprocessor: DepthPreprocessor) -> None:
    out_h, out_w = preprocessor.out_height, preprocessor.out_width
    if depth is not None and depth.ndim == 3 and (depth.shape[1] < out_h or depth.shape[2] < out_w):
        raise DatasetError(
            f"{source}: depth is stored at {depth.shape[2]}x{depth.shape[1]}, smaller than the network "
            f"input {out_w}x{out_h} (width x height): area resizing would upsample it"
        )


def prepare_shard_dir(
    path: Path, preprocessor: DepthPreprocessor, options: ShardOptions = DEFAULT_SHARD_OPTIONS
) -> PreparedData:
    """A shard directory read and preprocessed one shard at a time: what
    prepare_arrays(shard_dir_arrays(path)) gives (tested equal), holding one shard's full-resolution depth at
    a time instead of the dataset's (a DAgger round of 50k records is 7 GB of float16 depth at 320x240, and
    concatenating the shards doubled that). Error messages name the shard and the record within it."""
    from quad_il.data import DatasetError as CollectorDatasetError
    from quad_il.data.postprocess import iter_shard_arrays

    parts: list[PreparedData] = []
    shards = iter_shard_arrays(
        path,
        num_ctrl_pts=options.num_ctrl_pts,
        horizon_s=options.horizon_s,
        on_corrupt=options.on_corrupt,  # type: ignore[arg-type]
    )
    while True:
        try:  # the reader's errors (not this module's checks, which name the shard themselves)
            item = next(shards, None)
        except (CollectorDatasetError, ValueError) as e:
            raise DatasetError(f"{path}: cannot read as a shard dataset: {e}") from None
        if item is None:
            break
        name, fixed = item
        arrays = _npz_arrays(fixed)
        _check_depth_size(fixed.depth_m, str(path), preprocessor)
        parts.append(prepare_arrays(arrays, preprocessor, str(path / name))[0])
        del item, fixed, arrays  # the shard's full-resolution depth
    if not parts:
        raise DatasetError(f"{path}: cannot read as a shard dataset: dataset holds no records")
    data = concatenate(parts)
    first = parts[0].sources[0]
    data.sources = [
        SourceInfo(
            str(path), len(data.episode_id), first.depth_height, first.depth_width, first.format_version
        )
    ]
    return data


def load_dataset(
    paths: Sequence[str | Path], preprocessor: DepthPreprocessor, shards: ShardOptions = DEFAULT_SHARD_OPTIONS
) -> PreparedData:
    """Read, validate and preprocess every source; one PreparedData in the order of `paths`."""
    parts = []
    for path, kind in expand_paths(paths):
        if kind == "shards":
            parts.append(prepare_shard_dir(path, preprocessor, shards))
            continue
        arrays = read_source(path, kind, shards)
        _check_depth_size(arrays.get("depth_m"), str(path), preprocessor)
        parts.append(prepare_arrays(arrays, preprocessor, str(path))[0])
    return concatenate(parts)


# ------------------------------------------------------------------------------------------------------ split
@dataclass(frozen=True)
class Split:
    train_idx: NDArray[np.int64]
    val_idx: NDArray[np.int64]
    train_episodes: list[tuple[int, int]]  # (world_seed, episode_id)
    val_episodes: list[tuple[int, int]]
    unused_episodes: list[tuple[int, int]]  # training episodes left out by train_episode_fraction


def episode_keys(
    world_seed: NDArray[Any], episode_id: NDArray[Any]
) -> tuple[list[tuple[int, int]], np.ndarray]:
    """Sorted unique (world_seed, episode_id) pairs and, per sample, the index of its pair."""
    pairs = np.stack(
        [np.asarray(world_seed, dtype=np.uint64), np.asarray(episode_id).astype(np.uint64)], axis=1
    )
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    return [(int(a), int(np.int64(b))) for a, b in unique], inverse.reshape(-1)


SPLIT_METHODS = ("permuted", "hashed")


def episode_hash_fraction(key: tuple[int, int], seed: int) -> float:
    """A uniform number in [0, 1) that depends only on the episode (world_seed, episode_id) and `seed`."""
    digest = hashlib.blake2b(f"{seed}:{key[0]}:{key[1]}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "little") / 2.0**64


def split_by_episode(
    world_seed: NDArray[Any],
    episode_id: NDArray[Any],
    val_fraction: float,
    seed: int,
    train_episode_fraction: float = 1.0,
    method: str = "permuted",
) -> Split:
    """Seeded split of whole episodes into training and validation.

    An episode is a (world_seed, episode_id) pair, so no episode has samples on both sides.
    - `permuted`: round(E * val_fraction) (at least 1) episodes to validation by a permutation that depends on
      `seed` and the set of episodes, so adding a dataset moves episodes between the sides.
    - `hashed`: an episode is in validation when its hash with `seed` (episode_hash_fraction) is below
      `val_fraction`, so its side never depends on the other episodes: a DAgger round that adds datasets
      keeps every earlier episode where it was, and a warm-started network is validated on episodes it never
      trained on. The validation share is then val_fraction on average; at least one episode is on each side.
    `train_episode_fraction` < 1 keeps a seeded subset of the training episodes (for dataset-size experiments;
    the validation set stays the same).
    """
    if not 0.0 < val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in (0, 1), got {val_fraction}")
    if not 0.0 < train_episode_fraction <= 1.0:
        raise ValueError(f"train_episode_fraction must be in (0, 1], got {train_episode_fraction}")
    if method not in SPLIT_METHODS:
        raise ValueError(f"split method '{method}': one of {', '.join(SPLIT_METHODS)}")
    keys, inverse = episode_keys(world_seed, episode_id)
    num_ep = len(keys)
    if num_ep < 2:
        raise DatasetError(f"need at least 2 episodes to split into training and validation, got {num_ep}")
    rng = np.random.default_rng([seed, 0x5EED])
    if method == "hashed":
        u = np.array([episode_hash_fraction(k, seed) for k in keys])
        by_u = np.argsort(u, kind="stable")
        n_val = min(num_ep - 1, max(1, int(np.count_nonzero(u < val_fraction))))
        val_ep = np.sort(by_u[:n_val])
        train_order = rng.permutation(by_u[n_val:])
    else:
        n_val = min(num_ep - 1, max(1, round(num_ep * val_fraction)))
        order = rng.permutation(num_ep)
        val_ep = np.sort(order[:n_val])
        train_order = order[n_val:]
    n_train = max(1, math.ceil(len(train_order) * train_episode_fraction))
    train_ep = np.sort(train_order[:n_train])
    unused_ep = np.sort(train_order[n_train:])
    train_idx = np.flatnonzero(np.isin(inverse, train_ep)).astype(np.int64)
    val_idx = np.flatnonzero(np.isin(inverse, val_ep)).astype(np.int64)
    return Split(
        train_idx,
        val_idx,
        [keys[i] for i in train_ep],
        [keys[i] for i in val_ep],
        [keys[i] for i in unused_ep],
    )


# --------------------------------------------------------------------------------------------------- batching
@dataclass
class Batch:
    indices: NDArray[np.int64]  # dataset indices of the samples
    depth_x: Tensor  # float32 (B, 1, h, w)
    p_world_body: Tensor
    v_world: Tensor
    q_world_body: Tensor
    goal_world: Tensor
    target: Tensor  # (B, out_dim) in the training representation


class BatchLoader:
    """Batches of prepared samples in a seeded order, optionally prepared ahead by worker threads.

    The order of epoch e is a permutation drawn from numpy's PCG64 seeded with (seed, e): the same for every
    run and on resumption, and independent of `num_workers` (workers only compute batches ahead, in order).
    """

    def __init__(
        self,
        data: PreparedData,
        targets: Tensor,
        indices: NDArray[np.int64],
        batch_size: int,
        shuffle: bool,
        seed: int = 0,
        drop_last: bool = False,
        num_workers: int = 0,
    ) -> None:
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        if len(indices) == 0:
            raise DatasetError("no samples to batch")
        self.data = data
        self.targets = targets
        self.indices = np.asarray(indices, dtype=np.int64)
        self.batch_size = batch_size
        self.shuffle = shuffle
        self.seed = seed
        # A last batch of one sample would break BatchNorm in training mode, so drop_last only when needed.
        self.drop_last = drop_last and len(self.indices) >= batch_size
        self.num_workers = num_workers

    def __len__(self) -> int:
        n = len(self.indices)
        return n // self.batch_size if self.drop_last else math.ceil(n / self.batch_size)

    def order(self, epoch: int) -> NDArray[np.int64]:
        if not self.shuffle:
            return self.indices
        return self.indices[np.random.default_rng([self.seed, epoch]).permutation(len(self.indices))]

    def _make(self, idx: NDArray[np.int64]) -> Batch:
        t = torch.from_numpy(idx)
        d = self.data
        return Batch(
            idx,
            d.depth_x.index_select(0, t).float(),
            d.p_world_body.index_select(0, t),
            d.v_world.index_select(0, t),
            d.q_world_body.index_select(0, t),
            d.goal_world.index_select(0, t),
            self.targets.index_select(0, t),
        )

    def epoch(self, epoch: int) -> Iterator[Batch]:
        order = self.order(epoch)
        chunks = [order[i : i + self.batch_size] for i in range(0, len(order), self.batch_size)]
        if self.drop_last and len(chunks[-1]) < self.batch_size:
            chunks.pop()
        if self.num_workers == 0:
            for c in chunks:
                yield self._make(c)
            return
        window = 2 * self.num_workers
        with concurrent.futures.ThreadPoolExecutor(self.num_workers, thread_name_prefix="batch") as pool:
            pending = collections.deque(pool.submit(self._make, c) for c in chunks[:window])
            for i in range(len(chunks)):
                batch = pending.popleft().result()
                if i + window < len(chunks):
                    pending.append(pool.submit(self._make, chunks[i + window]))
                yield batch
