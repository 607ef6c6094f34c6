"""On-disk format of the Python (interactive) collector: one `.npz` file per episode, written atomically.

A file `episode_<episode_id:06d>.npz` is written as `<name>.partial`, flushed and fsynced, then renamed; the
directory is fsynced. A reader therefore sees complete files only; a `.partial` left by a killed collector is
the torn tail and is reported, never read. Format version 2 (version 1 files are still read), arrays
(N = records, K = the largest number of control points in the file, L = the largest knot count):

| key | shape, dtype | meaning |
|---|---|---|
| format_version | (), int64 | 2 |
| stamp_s | (N,) float64 | observation (depth frame) stamp, s |
| odom_stamp_s | (N,) float64 | stamp of the state's odometry (NaN: unknown; absent in version 1) |
| frame_seq, episode_id, round_index | (N,) int64 | lockstep frame counter, episode, round |
| p_world_body, v_world, goal_world | (N, 3) float64 | state (m, m/s), goal (m), world frame |
| q_world_body | (N, 4) float64 | attitude quaternion (x, y, z, w) |
| depth_m | (N, H, W) float32 | depth image in metres as published (absent: `has_depth` = 0) |
| features | (N, F) float64 | MEGA-DAgger observation features (absent: `has_features` = 0) |
| label_ctrl, label_knots | (N, K, 3), (N, L) float64 | the label B-spline (world frame), zero-padded |
| label_num_ctrl | (N,) int64 | its control points (knots: label_num_ctrl + label_order + 1) |
| label_order, label_traj_id | (N,) int64 | its degree and trajectory id |
| label_start_time_s | (N,) float64 | its start time |
| contrast_* | as label_*; contrast_mask (N,) bool | EIL's contrast action (zeros where the mask is False) |
| partition, controller | (N,) int8 | PARTITION_CODES / CONTROLLER_CODES (types.py) |
| source | (N,) unicode | "learner" or the expert's name |
| deviation_m, score, min_clearance_m | (N,) float64 | gate deviation, MEGA score, clearance (NaN: none) |

Rows may hold splines of different sizes and degrees (the expert's plans vary in length); version 1 files had
one K and order per file.
"""

from __future__ import annotations

import os
import zipfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from quad_il.imitation.bspline import SplineAction
from quad_il.imitation.types import (
    CONTROLLER_CODES,
    PARTITION_CODES,
    ImitationError,
    Observation,
    Record,
)

FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)
PARTIAL_SUFFIX = ".partial"

_PARTITION_BY_CODE = {v: k for k, v in PARTITION_CODES.items()}
_CONTROLLER_BY_CODE = {v: k for k, v in CONTROLLER_CODES.items()}


class DatasetError(ValueError):
    """A dataset file or directory is malformed; the message names the file and the field."""


def episode_filename(episode_id: int) -> str:
    return f"episode_{episode_id:06d}.npz"


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _spline_arrays(actions: Sequence[SplineAction | None], prefix: str) -> dict[str, np.ndarray]:
    present = [a for a in actions if a is not None]
    if not present:
        return {}
    k = max(a.num_ctrl for a in present)
    nk = max(a.knots.shape[0] for a in present)
    n = len(actions)
    ctrl = np.zeros((n, k, 3))
    knots = np.zeros((n, nk))
    num = np.zeros(n, dtype=np.int64)
    order = np.zeros(n, dtype=np.int64)
    start = np.zeros(n)
    traj = np.zeros(n, dtype=np.int64)
    for i, a in enumerate(actions):
        if a is None:
            continue
        ctrl[i, : a.num_ctrl] = a.ctrl_pts_world
        knots[i, : a.knots.shape[0]] = a.knots
        num[i], order[i], start[i], traj[i] = a.num_ctrl, a.order, a.start_time_s, a.traj_id
    return {
        f"{prefix}_ctrl": ctrl,
        f"{prefix}_knots": knots,
        f"{prefix}_num_ctrl": num,
        f"{prefix}_order": order,
        f"{prefix}_start_time_s": start,
        f"{prefix}_traj_id": traj,
    }


def records_to_arrays(records: Sequence[Record]) -> dict[str, np.ndarray]:
    if not records:
        raise ImitationError("no records to write")
    obs = [r.obs for r in records]
    has_depth = all(o.depth_m is not None for o in obs)
    if not has_depth and any(o.depth_m is not None for o in obs):
        raise ImitationError("either every record of an episode has a depth image or none has")
    has_features = all(o.features is not None for o in obs)
    out: dict[str, np.ndarray] = {
        "format_version": np.array(FORMAT_VERSION, dtype=np.int64),
        "stamp_s": np.array([o.stamp_s for o in obs]),
        "odom_stamp_s": np.array([o.odom_stamp_s for o in obs]),
        "frame_seq": np.array([o.frame_seq for o in obs], dtype=np.int64),
        "episode_id": np.array([o.episode_id for o in obs], dtype=np.int64),
        "round_index": np.array([r.round_index for r in records], dtype=np.int64),
        "p_world_body": np.stack([o.p_world_body for o in obs]),
        "v_world": np.stack([o.v_world for o in obs]),
        "q_world_body": np.stack([o.q_world_body for o in obs]),
        "goal_world": np.stack([o.goal_world for o in obs]),
        "has_depth": np.array(int(has_depth), dtype=np.int64),
        "has_features": np.array(int(has_features), dtype=np.int64),
        "partition": np.array([PARTITION_CODES[r.partition] for r in records], dtype=np.int8),
        "controller": np.array([CONTROLLER_CODES[r.controller] for r in records], dtype=np.int8),
        "source": np.array([r.source for r in records], dtype=np.str_),
        "deviation_m": np.array([r.deviation_m for r in records]),
        "score": np.array([r.score for r in records]),
        "min_clearance_m": np.array([r.min_clearance_m for r in records]),
        "contrast_mask": np.array([r.contrast is not None for r in records], dtype=bool),
    }
    if has_depth:
        shapes = {o.depth_m.shape for o in obs if o.depth_m is not None}
        if len(shapes) != 1:
            raise ImitationError(f"depth images of one episode must share a size, got {sorted(shapes)}")
        out["depth_m"] = np.stack([o.depth_m for o in obs if o.depth_m is not None]).astype(np.float32)
    if has_features:
        dims = {o.features.shape for o in obs if o.features is not None}
        if len(dims) != 1:
            raise ImitationError(f"observation features of one episode must share a size, got {sorted(dims)}")
        out["features"] = np.stack([o.features for o in obs if o.features is not None])
    out.update(_spline_arrays([r.label for r in records], "label"))
    out.update(_spline_arrays([r.contrast for r in records], "contrast"))
    return out


def write_episode(directory: str | Path, episode_id: int, records: Sequence[Record]) -> Path:
    """Atomically write one episode's records; returns the final path. Refuses to overwrite."""
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    final = d / episode_filename(episode_id)
    if final.exists():
        raise DatasetError(f"{final} already exists; episodes are written once")
    arrays = records_to_arrays(records)
    partial = final.with_name(final.name + PARTIAL_SUFFIX)
    try:
        with open(partial, "wb") as fh:
            np.savez(fh, **arrays)
            fh.flush()
            os.fsync(fh.fileno())
    except OSError as e:
        # Disk full (ENOSPC, or EFBIG past RLIMIT_FSIZE) or an I/O error: the torn file is removed (it
        # would only ever be reported as a leftover .partial) and the error names the file; episodes
        # written before stay complete.
        partial.unlink(missing_ok=True)
        raise DatasetError(
            f"cannot write episode {episode_id} to {partial}: {e.strerror or e}; the partial file was "
            "removed, earlier episodes are complete"
        ) from None
    os.replace(partial, final)
    _fsync_dir(d)
    return final


def _get(data: np.lib.npyio.NpzFile, path: Path, key: str) -> np.ndarray:
    if key not in data.files:
        raise DatasetError(f"{path}: missing field '{key}'")
    try:
        return data[key]
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise DatasetError(f"{path}: field '{key}' is unreadable: {e}") from None


def _splines(
    data: np.lib.npyio.NpzFile, path: Path, prefix: str, mask: np.ndarray, version: int
) -> list[SplineAction | None]:
    if not mask.any():
        return [None] * mask.shape[0]
    ctrl = _get(data, path, f"{prefix}_ctrl")
    knots = _get(data, path, f"{prefix}_knots")
    order = _get(data, path, f"{prefix}_order")
    start = _get(data, path, f"{prefix}_start_time_s")
    traj = _get(data, path, f"{prefix}_traj_id")
    if version >= 2:
        num = _get(data, path, f"{prefix}_num_ctrl")
    else:
        num = np.full(mask.shape[0], ctrl.shape[1], dtype=np.int64)
    out: list[SplineAction | None] = []
    for i in range(mask.shape[0]):
        if not mask[i]:
            out.append(None)
            continue
        k, p = int(num[i]), int(order[i])
        if not 0 < k <= ctrl.shape[1] or k + p + 1 > knots.shape[1]:
            raise DatasetError(
                f"{path}: record {i}: {prefix}_num_ctrl {k} with order {p} does not fit the arrays "
                f"({ctrl.shape[1]} control points, {knots.shape[1]} knots)"
            )
        try:
            out.append(SplineAction(ctrl[i, :k], knots[i, : k + p + 1], p, float(start[i]), int(traj[i])))
        except ValueError as e:
            raise DatasetError(f"{path}: record {i}: bad {prefix} B-spline: {e}") from None
    return out


def read_episode(path: str | Path) -> list[Record]:
    p = Path(path)
    if p.name.endswith(PARTIAL_SUFFIX):
        raise DatasetError(f"{p} is an incomplete (.partial) file")
    if not p.is_file():
        raise DatasetError(f"{p}: no such file")
    try:
        data = np.load(p, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise DatasetError(f"{p}: not a readable .npz file: {e}") from None
    with data:
        version = int(_get(data, p, "format_version"))
        if version not in READABLE_VERSIONS:
            raise DatasetError(
                f"{p}: format_version {version}, this reader understands {list(READABLE_VERSIONS)}"
            )
        stamp = _get(data, p, "stamp_s")
        n = stamp.shape[0]
        fields = {
            k: _get(data, p, k)
            for k in (
                "frame_seq",
                "episode_id",
                "round_index",
                "p_world_body",
                "v_world",
                "q_world_body",
                "goal_world",
                "partition",
                "controller",
                "source",
                "deviation_m",
                "score",
                "min_clearance_m",
                "contrast_mask",
            )
        }
        for k, v in fields.items():
            if v.shape[0] != n:
                raise DatasetError(f"{p}: field '{k}' has {v.shape[0]} rows, stamp_s has {n}")
        depth = _get(data, p, "depth_m") if int(_get(data, p, "has_depth")) else None
        feats = _get(data, p, "features") if int(_get(data, p, "has_features")) else None
        odom_stamp = _get(data, p, "odom_stamp_s") if version >= 2 else np.full(n, np.nan)
        labels = _splines(data, p, "label", np.ones(n, dtype=bool), version)
        contrasts = _splines(data, p, "contrast", fields["contrast_mask"].astype(bool), version)
        records: list[Record] = []
        for i in range(n):
            try:
                obs = Observation(
                    stamp_s=float(stamp[i]),
                    frame_seq=int(fields["frame_seq"][i]),
                    episode_id=int(fields["episode_id"][i]),
                    p_world_body=fields["p_world_body"][i],
                    v_world=fields["v_world"][i],
                    q_world_body=fields["q_world_body"][i],
                    goal_world=fields["goal_world"][i],
                    depth_m=None if depth is None else depth[i],
                    features=None if feats is None else feats[i],
                    odom_stamp_s=float(odom_stamp[i]),
                )
                partition = _PARTITION_BY_CODE[int(fields["partition"][i])]
                controller = _CONTROLLER_BY_CODE[int(fields["controller"][i])]
            except (ValueError, KeyError) as e:
                raise DatasetError(f"{p}: record {i}: {e}") from None
            label = labels[i]
            if label is None:
                raise DatasetError(f"{p}: record {i} has no label")
            records.append(
                Record(
                    obs=obs,
                    label=label,
                    partition=partition,
                    source=str(fields["source"][i]),
                    controller=controller,
                    round_index=int(fields["round_index"][i]),
                    deviation_m=float(fields["deviation_m"][i]),
                    contrast=contrasts[i],
                    score=float(fields["score"][i]),
                    min_clearance_m=float(fields["min_clearance_m"][i]),
                )
            )
    return records


def list_episodes(directory: str | Path) -> tuple[list[Path], list[Path]]:
    """(complete episode files sorted by name, leftover .partial files) of a data directory."""
    d = Path(directory)
    if not d.is_dir():
        raise DatasetError(f"{d}: not a directory")
    complete = sorted(d.glob("episode_*.npz"))
    partial = sorted(d.glob("episode_*.npz" + PARTIAL_SUFFIX))
    return complete, partial
