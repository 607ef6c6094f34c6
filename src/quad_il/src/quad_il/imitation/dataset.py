"""The interactive collector's demonstrations on disk: the cpp_data_collector dataset format (shards +
manifest, docs/data_format.md), written by quad_il.data.writer, read by quad_il.data.shards and `read_dataset`
like every other dataset of the project.

A round's data directory is one dataset. Its manifest's run_info names the profile below
(`record_profile: quad_il.imitation/1`), the round and the algorithm. A record is one imitation-learning
Record; the fields that a planner's record spends on the planner's status and timings carry the learner's
bookkeeping (docs/data_format.md, "Records of the interactive collector"):

| field | content |
|---|---|
| episode_id, world_seed | the simulator's episode id and world seed |
| sim_time_s, depth_stamp_s | the observation's (depth frame's) stamp |
| odom_stamp_s | the stamp of the odometry the state came from (the observation's stamp when unknown) |
| p_world_body, v_world, q_world_body, goal_world, depth_code | the observation (w_body = 0: not recorded) |
| bspline_* , knots, ctrl_pts_world | the label (the trainer's target) |
| plan_status_code | the partition code (0 demo, 1 intervention, 2 good, 3 bad: quad_il.data.partitions) |
| plan_status_text | "<controller> <source>": who flew this step and whose plan the label is |
| t_map_update_ms / t_frontend_ms / t_optimization_ms | deviation_m / score / min_clearance_m |
| flags | bits 1 / 2 / 4: the value above is present (absent: 0 in the record, NaN when read back) |

Not stored (no reader used them from disk): MEGA-DAgger's observation features, EIL's contrast action, the
lockstep frame counter (a record read back has its dataset seq as frame_seq).
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from quad_il.data.format import DatasetError, NotADatasetError, decode_depth_codes, record_dtype
from quad_il.data.partitions import PARTITION_CODES
from quad_il.data.shards import open_dataset
from quad_il.data.writer import (
    DatasetWriter,
    PlanRecordData,
    WriterConfig,
    encode_record,
    layout_params,
    load_writer_config,
    validate,
)
from quad_il.imitation.bspline import SplineAction
from quad_il.imitation.types import Controller, ImitationError, Observation, Record
from quad_il.tools.repo import repo_path

RECORD_PROFILE = "quad_il.imitation/1"
FLAG_DEVIATION, FLAG_SCORE, FLAG_CLEARANCE = 1, 2, 4
_PARTITION_BY_CODE = {v: k for k, v in PARTITION_CODES.items()}
_CONTROLLERS = {c.value: c for c in Controller}


def plan_record(r: Record, world_seed: int) -> PlanRecordData:
    """One imitation Record as a dataset record (the table above)."""
    o, a = r.obs, r.label
    if o.depth_m is None:
        raise ImitationError(f"record at {o.stamp_s:.3f} s has no depth image: a dataset record needs one")
    extras = (r.deviation_m, r.score, r.min_clearance_m)
    flags = sum(bit for bit, v in zip((FLAG_DEVIATION, FLAG_SCORE, FLAG_CLEARANCE), extras, strict=True)
                if math.isfinite(v))  # fmt: skip
    return PlanRecordData(
        episode_id=o.episode_id,
        world_seed=int(world_seed),
        sim_time_s=o.stamp_s,
        depth_m=o.depth_m,
        depth_stamp_s=o.stamp_s,
        odom_stamp_s=o.odom_stamp_s if math.isfinite(o.odom_stamp_s) else o.stamp_s,
        p_world_body=o.p_world_body,
        v_world=o.v_world,
        q_world_body=o.q_world_body,
        w_body=(0.0, 0.0, 0.0),
        goal_world=o.goal_world,
        order=a.order,
        traj_id=a.traj_id,
        start_time_s=a.start_time_s,
        knots=a.knots,
        ctrl_pts_world=a.ctrl_pts_world,
        status_code=PARTITION_CODES[r.partition],
        status_text=f"{r.controller.value} {r.source}",
        timings_ms=(*(v if math.isfinite(v) else 0.0 for v in extras), 0.0),  # type: ignore[arg-type]
        flags=flags,
    )


def default_writer_config(
    output_dir: str | Path, image_hw: tuple[int, int], **replace: object
) -> WriterConfig:
    """config/collector.yaml (the project's one writer config) for a round's data directory."""
    h, w = image_hw
    return load_writer_config(
        repo_path("config", "collector.yaml"),
        output_dir=str(output_dir),
        image_width=int(w),
        image_height=int(h),
        **replace,
    )


class EpisodeWriter:
    """The collector's writer of one round's dataset: episodes appended as they end, fsynced each time.

    The dataset (and its manifest) is created at the first episode with records, when the image size is
    known; a round without records leaves no dataset. `writer_config` replaces keys of config/collector.yaml
    (camera intrinsics from camera_info, software_commit)."""

    def __init__(self, directory: str | Path, run_info: dict[str, str], **writer_config: object) -> None:
        self.directory = Path(directory)
        self.run_info = {"record_profile": RECORD_PROFILE, **run_info}
        self.writer_config = writer_config
        self.writer: DatasetWriter | None = None
        self.written = 0
        self.rejected: list[str] = []

    def write(self, world_seed: int, records: Sequence[Record], **writer_config: object) -> int:
        """Appends an episode's records; returns how many were written (invalid ones are counted in the
        manifest and kept in `rejected`). ImitationError when the writer failed (disk full: the error
        names the file)."""
        if not records:
            return 0
        plans = [plan_record(r, world_seed) for r in records]  # ImitationError for a record without depth
        if self.writer is None:
            shape = np.shape(plans[0].depth_m)
            cfg = default_writer_config(self.directory, shape, **{**self.writer_config, **writer_config})
            self.writer = DatasetWriter(cfg, self.run_info)
        n = 0
        for r, plan in zip(records, plans, strict=True):
            status, detail = self.writer.record(plan)
            if status == "queued":
                n += 1
            elif status == "rejected":
                self.rejected.append(f"record at {r.obs.stamp_s:.3f} s: {detail}")
            else:
                self.written += n
                raise ImitationError(f"dataset writer failed: {detail}")
        self.writer.flush()
        self.written += n
        if self.writer.error:
            raise ImitationError(f"dataset writer failed: {self.writer.error}")
        return n

    def finalize(self) -> bool:
        return self.writer.finalize() if self.writer is not None else True


def write_dataset(
    directory: str | Path, records: Sequence[Record], *, world_seed: int = 0, round_index: int | None = None
) -> Path:
    """A complete dataset of `records` in one call (tools and tests); ImitationError if one is invalid."""
    if not records:
        raise ImitationError("no records to write")
    rounds = {r.round_index for r in records}
    info = {"round_index": str(round_index if round_index is not None else min(rounds))}
    w = EpisodeWriter(directory, info, fsync=False)
    w.write(world_seed, records)
    if w.rejected:
        raise ImitationError(f"{directory}: {w.rejected[0]}")
    w.finalize()
    return Path(directory)


def shard_records(records: Sequence[Record], world_seed: int = 0) -> np.ndarray:
    """Records as an in-memory array of dataset records (what a round's dataset would hold), for the
    conversion of records that were never written."""
    if not records:
        raise ImitationError("no records")
    if any(r.obs.depth_m is None for r in records):
        raise ImitationError("records without depth images cannot be written or trained on")
    shapes = {r.obs.depth_m.shape for r in records}  # type: ignore[union-attr]
    if len(shapes) != 1:
        raise ImitationError(f"depth images of different sizes: {sorted(shapes)}")
    cfg = default_writer_config(os.devnull, shapes.pop())
    dtype = record_dtype(*layout_params(cfg))
    out = np.zeros(len(records), dtype=dtype)
    for i, r in enumerate(records):
        pr = plan_record(r, world_seed)
        why = validate(pr, cfg)
        if why:
            raise ImitationError(f"record {i}: {why}")
        out[i : i + 1] = np.frombuffer(encode_record(pr, i, dtype), dtype=dtype)
    return out


@dataclasses.dataclass(frozen=True)
class RoundData:
    """The valid records of one round's dataset (shard records, seq order) and its round index."""

    path: Path
    round_index: int
    records: np.ndarray
    manifest: dict[str, Any] | None


def read_round(directory: str | Path) -> RoundData | None:
    """A round's dataset (verified: a CRC mismatch or a torn completed shard is an error; a killed writer's
    torn tail is skipped); None for a directory without a dataset (a round that recorded nothing)."""
    d = Path(directory)
    if not d.is_dir():
        raise NotADatasetError(f"{d}: not a directory")
    try:
        ds = open_dataset(d)
    except NotADatasetError:
        names = [p.name for p in d.iterdir()]
        if any(n.startswith(("shard_", "manifest")) for n in names):
            raise
        if any(n.startswith("episode_") and n.endswith(".npz") for n in names):
            raise NotADatasetError(
                f"{d}: holds episode_*.npz files of the interactive collector's former format (removed in "
                "issue 31); collect the round again"
            ) from None
        return None
    info = (ds.manifest or {}).get("run_info") or {}
    if info.get("record_profile") != RECORD_PROFILE:
        raise DatasetError(
            f"{d}: not an interactive collector's dataset (run_info.record_profile is "
            f"{info.get('record_profile')!r}, expected {RECORD_PROFILE!r})"
        )
    try:
        round_index = int(info["round_index"])
    except (KeyError, ValueError):
        raise DatasetError(f"{d}: run_info.round_index is missing or not an integer") from None
    chunks = [records for _, records, _ in ds.valid_record_arrays()]
    # Copied into an array of the shards' own dtype (np.concatenate would pack the structured dtype, moving
    # the CRC off its offset in the raw bytes).
    dtype = ds.shards[0].dtype if ds.shards else np.dtype([])
    records = np.zeros(sum(len(c) for c in chunks), dtype=dtype)
    start = 0
    for c in chunks:
        records[start : start + len(c)] = c
        start += len(c)
    return RoundData(d, round_index, records, ds.manifest)


def to_records(data: RoundData) -> list[Record]:
    """Dataset records back into Records (what was stored: the table above)."""
    out = []
    for rec in data.records:
        n, k = int(rec["num_ctrl_pts"]), int(rec["num_knots"])
        controller, _, source = bytes(rec["plan_status_text"]).rstrip(b"\0").decode("utf-8").partition(" ")
        flags = int(rec["flags"])
        t = (float(rec["t_map_update_ms"]), float(rec["t_frontend_ms"]), float(rec["t_optimization_ms"]))
        extras = [v if flags & bit else math.nan for bit, v in zip((1, 2, 4), t, strict=True)]
        where = f"{data.path} record seq {int(rec['seq'])}"
        try:
            obs = Observation(
                stamp_s=float(rec["depth_stamp_s"]),
                frame_seq=int(rec["seq"]),
                episode_id=int(rec["episode_id"]),
                p_world_body=rec["p_world_body"],
                v_world=rec["v_world"],
                q_world_body=rec["q_world_body"],
                goal_world=rec["goal_world"],
                depth_m=decode_depth_codes(rec["depth_code"]),
                odom_stamp_s=float(rec["odom_stamp_s"]),
            )
            label = SplineAction(
                rec["ctrl_pts_world"][:n],
                rec["knots"][:k],
                int(rec["bspline_order"]),
                float(rec["bspline_start_time_s"]),
                int(rec["bspline_traj_id"]),
            )
            partition = _PARTITION_BY_CODE[int(rec["plan_status_code"])]
            ctrl = _CONTROLLERS[controller]
        except (ValueError, KeyError) as e:
            raise DatasetError(f"{where}: not an interactive collector's record: {e}") from None
        out.append(
            Record(
                obs=obs,
                label=label,
                partition=partition,
                source=source,
                controller=ctrl,
                round_index=data.round_index,
                deviation_m=extras[0],
                score=extras[1],
                min_clearance_m=extras[2],
            )
        )
    return out


def read_records(directory: str | Path) -> list[Record]:
    """Every valid record of a round's dataset ([] without a dataset)."""
    data = read_round(directory)
    return [] if data is None else to_records(data)


def episodes(records: Sequence[Record]) -> list[list[Record]]:
    """Records grouped by episode, in order of first appearance."""
    groups: dict[int, list[Record]] = {}
    for r in records:
        groups.setdefault(r.obs.episode_id, []).append(r)
    return list(groups.values())
