"""The Python collector's episode files -> the training npz contract (the trainer's reader), and one round's
training step for imitation_learning_manager.py.

    python -m quad_il.imitation.convert --data DIR[,DIR...] --out dataset.npz [--num-ctrl-pts 10]
        [--horizon-s 2.0] [--partitions demo,intervention] [--stride N]
    python -m quad_il.imitation.convert train --data-dirs DIR[,DIR...] --checkpoint-dir CKPT
        --config config/train.yaml [--set key=value ...] [--policy-file policy.ts] [--extra-data DATASET ...]

The trainer (training_only/train_on_cpp_datasets.py, quad_il.learning.dataset) reads `.npz` files of the C++
collector's postprocessing (quad_il.data.postprocess: K control points of a uniform cubic B-spline over
horizon_s seconds from the depth stamp, fitted by least squares to the expert's spline). This module writes
exactly that contract from episode files: each record's label B-spline is sampled at the same times (from the
observation stamp, held at its ends) and fitted with the same matrix, so both collectors' data are
interchangeable. Mapping of the fields:

- `depth_m` float16 (as the C++ postprocessing stores it), `depth_stamp_s` = `sim_time_s` = the observation
  stamp, `odom_stamp_s` = the odometry stamp the state came from (the observation stamp where unknown);
- `world_seed` = the round index and `episode_id` = the simulator's episode id, so an episode is identified
  by (round, episode) and rounds never share an episode key (the trainer splits by episode);
- `w_body` = 0 (not recorded; the policy does not use it), `record_seq` = the lockstep frame counter,
  `plan_status_code` = the record's partition code, `fit_rms_m` = the fit residual.

The array `il_partition` (int32 partition codes, `quad_il.imitation.types.PARTITION_CODES`) is added for the
trainer's EIL loss. Only the partitions a regression loss trains on are kept by default (DEMO: BC and DAgger;
INTERVENTION: HG-DAgger, EIL's intervention rows, MEGA-DAgger); EIL's GOOD/BAD rows are converted with
`--partitions demo,intervention,good,bad` and trained on with `optim.loss=eil`.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from quad_il.data.bspline import basis_matrix, fit_matrix, uniform_knots
from quad_il.data.format import FORMAT_VERSION as NPZ_FORMAT_VERSION
from quad_il.data.postprocess import (
    FIT_DEGREE,
    FixedSizeArrays,
    ResampleConfig,
    world_to_local,
    yaw_from_quaternion_xyzw,
)
from quad_il.imitation.dataset import DatasetError, list_episodes, read_episode
from quad_il.imitation.types import IL_PARTITION_KEY, PARTITION_CODES, Partition, Record

DEFAULT_PARTITIONS = (Partition.DEMO, Partition.INTERVENTION)


def parse_partitions(text: str) -> tuple[Partition, ...]:
    names = [t.strip() for t in text.split(",") if t.strip()]
    try:
        return tuple(Partition(n) for n in names)
    except ValueError:
        raise DatasetError(
            f"--partitions {text!r}: each must be one of {[p.value for p in Partition]}"
        ) from None


def collect_records(
    dirs: Sequence[str | Path], partitions: Sequence[Partition] = DEFAULT_PARTITIONS, stride: int = 1
) -> tuple[list[Record], dict[str, int]]:
    """Every record of the complete episode files in `dirs` whose partition is wanted; counts of the rest.

    stride N keeps every N-th wanted record of each episode (the first included): the collector records every
    lockstep frame (30 Hz), whose neighbours are nearly identical; the C++ collector's BC data is ~2 Hz.
    """
    if stride < 1:
        raise DatasetError(f"--stride must be >= 1, got {stride}")
    records: list[Record] = []
    skipped: dict[str, int] = {}
    for d in dirs:
        files, partial = list_episodes(d)
        if partial:
            print(f"convert: {d}: ignoring {len(partial)} incomplete .partial file(s)", file=sys.stderr)
        for f in files:
            wanted = 0
            for r in read_episode(f):
                if r.partition not in partitions:
                    skipped[r.partition.value] = skipped.get(r.partition.value, 0) + 1
                    continue
                if wanted % stride == 0:
                    records.append(r)
                else:
                    skipped["stride"] = skipped.get("stride", 0) + 1
                wanted += 1
    return records, skipped


def records_to_npz_arrays(
    records: Sequence[Record], num_ctrl_pts: int = 10, horizon_s: float = 2.0
) -> FixedSizeArrays:
    if not records:
        raise DatasetError("no records to convert (no episode files, or none with a wanted partition)")
    if any(r.obs.depth_m is None for r in records):
        raise DatasetError("records without depth images cannot be trained on")
    shapes = {r.obs.depth_m.shape for r in records}  # type: ignore[union-attr]
    if len(shapes) != 1:
        raise DatasetError(f"depth images of different sizes: {sorted(shapes)}")
    cfg = ResampleConfig(num_ctrl_pts=num_ctrl_pts, horizon_s=horizon_s)
    s = cfg.sample_times_s
    fit = fit_matrix(cfg.num_ctrl_pts, FIT_DEGREE, cfg.knot_dt_s, s)  # (K, M)
    basis = basis_matrix(
        uniform_knots(cfg.num_ctrl_pts, FIT_DEGREE, cfg.knot_dt_s), cfg.num_ctrl_pts, FIT_DEGREE, s
    )
    y = np.stack([r.label.positions(r.obs.stamp_s + s) for r in records])  # (N, M, 3)
    ctrl_world = np.einsum("km,nmd->nkd", fit, y)
    resid = np.einsum("mk,nkd->nmd", basis, ctrl_world) - y
    rms = np.sqrt(np.mean(np.sum(resid * resid, axis=-1), axis=-1))
    p = np.stack([r.obs.p_world_body for r in records])
    q = np.stack([r.obs.q_world_body for r in records])
    stamp = np.array([r.obs.stamp_s for r in records])
    odom = np.array([r.obs.odom_stamp_s for r in records])
    odom = np.where(np.isfinite(odom), odom, stamp)
    f32 = np.float32
    n = len(records)
    return FixedSizeArrays(
        depth_m=np.stack([r.obs.depth_m for r in records]).astype(np.float16),  # type: ignore[misc]
        episode_id=np.array([r.obs.episode_id for r in records], dtype=np.int64),
        world_seed=np.array([r.round_index for r in records], dtype=np.uint64),
        sim_time_s=stamp.astype(np.float64),
        depth_stamp_s=stamp.astype(np.float64),
        odom_stamp_s=odom.astype(np.float64),
        p_world_body=p.astype(f32),
        v_world=np.stack([r.obs.v_world for r in records]).astype(f32),
        q_world_body=q.astype(f32),
        w_body=np.zeros((n, 3), dtype=f32),
        goal_world=np.stack([r.obs.goal_world for r in records]).astype(f32),
        bspline_ctrl_world=ctrl_world.astype(f32),
        bspline_ctrl_local=world_to_local(ctrl_world, p, yaw_from_quaternion_xyzw(q)).astype(f32),
        record_seq=np.array([r.obs.frame_seq for r in records], dtype=np.uint64),
        plan_status_code=np.array([PARTITION_CODES[r.partition] for r in records], dtype=np.int32),
        fit_rms_m=rms.astype(f32),
        num_ctrl_pts=cfg.num_ctrl_pts,
        horizon_s=cfg.horizon_s,
        format_version=NPZ_FORMAT_VERSION,
    )


def convert(
    dirs: Sequence[str | Path],
    out: str | Path,
    num_ctrl_pts: int = 10,
    horizon_s: float = 2.0,
    partitions: Sequence[Partition] = DEFAULT_PARTITIONS,
    stride: int = 1,
) -> tuple[Path, int, dict[str, int]]:
    records, skipped = collect_records(dirs, partitions, stride)
    arrays = records_to_npz_arrays(records, num_ctrl_pts, horizon_s)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.stem + ".partial.npz")
    # il_partition: what the trainer's EIL loss (optim.loss = eil) needs to know of each row.
    arrays.save(tmp, extra={IL_PARTITION_KEY: arrays.plan_status_code.astype(np.int32)})
    tmp.replace(out)
    return out, len(arrays), skipped


def train_round(args: argparse.Namespace) -> int:
    """Convert rounds 0..r, train, and put the exported policy where the next round's learner looks."""
    ckpt = Path(args.checkpoint_dir)
    ckpt.mkdir(parents=True, exist_ok=True)
    dirs = [d for d in args.data_dirs.split(",") if d]
    npz, n, skipped = convert(
        dirs,
        ckpt / "dataset.npz",
        args.num_ctrl_pts,
        args.horizon_s,
        parse_partitions(args.partitions),
        args.stride,
    )
    print(f"convert: {n} records from {len(dirs)} round(s) -> {npz}; skipped {skipped}", file=sys.stderr)
    root = Path(os.environ.get("QUAD_IL_ROOT") or Path(__file__).resolve().parents[5])
    trainer = root / "training_only" / "train_on_cpp_datasets.py"
    cmd = [sys.executable, str(trainer), "--data", str(npz), "--out", str(ckpt), "--name", "train"]
    for extra in args.extra_data:  # e.g. the behaviour-cloning dataset every round aggregates with
        cmd += ["--data", extra]
    for c in args.config:
        cmd += ["--config", c]
    for kv in args.set:
        cmd += ["--set", kv]
    code = subprocess.call(cmd)
    if code != 0:
        return code  # the converted copy stays for a look at what was trained on; a retry rewrites it
    exported = ckpt / "train" / "policy.ts"
    if not exported.is_file():
        print(f"convert: training wrote no {exported}", file=sys.stderr)
        return 1
    shutil.copyfile(exported, ckpt / args.policy_file)
    if not args.keep_dataset:
        # The converted copy holds every round so far (GBs by the fourth round); the round directories it was
        # made from stay, and the same command makes it again.
        size_mb = npz.stat().st_size / 1e6
        npz.unlink()
        print(
            f"convert: removed the converted copy {npz} ({size_mb:.0f} MB; --keep-dataset keeps it)",
            file=sys.stderr,
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "train":
        ap = argparse.ArgumentParser(prog="quad_il.imitation.convert train")
        ap.add_argument("--data-dirs", required=True, help="comma-separated round data directories")
        ap.add_argument("--checkpoint-dir", required=True)
        ap.add_argument("--config", action="append", default=[])
        ap.add_argument("--set", action="append", default=[])
        ap.add_argument("--policy-file", default="policy.ts")
        ap.add_argument("--num-ctrl-pts", type=int, default=10)
        ap.add_argument("--horizon-s", type=float, default=2.0)
        ap.add_argument("--partitions", default="demo,intervention")
        ap.add_argument("--stride", type=int, default=1, help="keep every N-th record of each episode")
        ap.add_argument(
            "--keep-dataset",
            action="store_true",
            help="keep checkpoint/dataset.npz after a successful training (default: removed; regenerable)",
        )
        ap.add_argument(
            "--extra-data",
            action="append",
            default=[],
            help="a dataset trained on with the rounds' data (e.g. the BC dataset); repeat for several",
        )
        args = ap.parse_args(argv[1:])
        try:
            return train_round(args)
        except DatasetError as e:
            print(f"convert: error: {e}", file=sys.stderr)
            return 2
    ap = argparse.ArgumentParser(prog="quad_il.imitation.convert", description=__doc__.splitlines()[0])
    ap.add_argument("--data", required=True, help="comma-separated data directories of episode files")
    ap.add_argument("--out", required=True)
    ap.add_argument("--num-ctrl-pts", type=int, default=10)
    ap.add_argument("--horizon-s", type=float, default=2.0)
    ap.add_argument("--partitions", default="demo,intervention")
    ap.add_argument("--stride", type=int, default=1, help="keep every N-th record of each episode")
    args = ap.parse_args(argv)
    try:
        out, n, skipped = convert(
            [d for d in args.data.split(",") if d],
            args.out,
            args.num_ctrl_pts,
            args.horizon_s,
            parse_partitions(args.partitions),
            args.stride,
        )
    except DatasetError as e:
        print(f"convert: error: {e}", file=sys.stderr)
        return 2
    print(f"{n} records -> {out}; skipped {skipped}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
