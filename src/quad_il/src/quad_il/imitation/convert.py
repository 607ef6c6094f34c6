"""Round datasets of the interactive collector -> the training npz contract (the trainer's reader), and one
round's training step for imitation_learning_manager.py.

    python -m quad_il.imitation.convert --data DIR[,DIR...] --out dataset.npz [--num-ctrl-pts 10]
        [--horizon-s 2.0] [--partitions demo,intervention] [--stride N]
    python -m quad_il.imitation.convert train --data-dirs DIR[,DIR...] --checkpoint-dir CKPT
        --config config/train.yaml [--set key=value ...] [--policy-file policy.ts] [--extra-data DATASET ...]

A round's data directory is a dataset of the one demonstration format (shards + manifest, written by the
collector through quad_il.data.writer; quad_il.imitation.dataset says what its records hold). The conversion
is the C++ collector's postprocessing (quad_il.data.postprocess.records_to_arrays: K control points of a
uniform cubic B-spline over horizon_s seconds from the depth stamp, fitted by least squares to the label) on
the records of the wanted partitions, with two columns set for the interactive rounds:

- `world_seed` = the round index (the dataset's run_info.round_index), so an episode is identified by
  (round, episode) and rounds never share an episode key (the trainer splits by episode);
- `il_partition` (int32 partition codes, `quad_il.data.partitions.PARTITION_CODES`, = plan_status_code), for
  the trainer's EIL loss.

Only the partitions a regression loss trains on are kept by default (DEMO: BC and DAgger; INTERVENTION:
HG-DAgger, EIL's intervention rows, MEGA-DAgger); EIL's GOOD/BAD rows are converted with
`--partitions demo,intervention,good,bad` and trained on with `optim.loss=eil`.
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from quad_il.data.format import DatasetError
from quad_il.data.partitions import IL_PARTITION_KEY, PARTITION_CODES, Partition
from quad_il.data.postprocess import FixedSizeArrays, records_to_arrays
from quad_il.imitation.dataset import read_round, shard_records
from quad_il.imitation.types import ImitationError, Record
from quad_il.tools.cli import HelpFormatter

DEFAULT_PARTITIONS = (Partition.DEMO, Partition.INTERVENTION)


def parse_partitions(text: str) -> tuple[Partition, ...]:
    names = [t.strip() for t in text.split(",") if t.strip()]
    try:
        return tuple(Partition(n) for n in names)
    except ValueError:
        raise DatasetError(
            f"--partitions {text!r}: each must be one of {[p.value for p in Partition]}"
        ) from None


def select_records(
    dirs: Sequence[str | Path], partitions: Sequence[Partition] = DEFAULT_PARTITIONS, stride: int = 1
) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """(dataset records of the wanted partitions, each one's round index, counts of what was skipped).

    stride N keeps every N-th wanted record of each episode (the first included): the collector records every
    lockstep frame (30 Hz), whose neighbours are nearly identical; the C++ collector's BC data is ~2 Hz. A
    directory without a dataset (a round that recorded nothing) contributes nothing.
    """
    if stride < 1:
        raise DatasetError(f"--stride must be >= 1, got {stride}")
    by_code = {PARTITION_CODES[p]: p for p in Partition}
    wanted_codes = {PARTITION_CODES[p] for p in partitions}
    chunks: list[np.ndarray] = []
    rounds: list[np.ndarray] = []
    skipped: dict[str, int] = {}
    for d in dirs:
        data = read_round(d)
        if data is None or len(data.records) == 0:
            continue
        keep = np.zeros(len(data.records), dtype=bool)
        seen: dict[int, int] = {}  # episode -> wanted records so far
        for i, (code, episode) in enumerate(
            zip(data.records["plan_status_code"], data.records["episode_id"], strict=True)
        ):
            if int(code) not in wanted_codes:
                name = by_code[int(code)].value if int(code) in by_code else f"code {int(code)}"
                skipped[name] = skipped.get(name, 0) + 1
                continue
            n = seen.get(int(episode), 0)
            seen[int(episode)] = n + 1
            if n % stride == 0:
                keep[i] = True
            else:
                skipped["stride"] = skipped.get("stride", 0) + 1
        chunks.append(data.records[keep])
        rounds.append(np.full(int(keep.sum()), data.round_index, dtype=np.uint64))
    if not chunks or sum(len(c) for c in chunks) == 0:
        return np.zeros(0), np.zeros(0, dtype=np.uint64), skipped
    return np.concatenate(chunks), np.concatenate(rounds), skipped


def shard_records_to_npz_arrays(
    records: np.ndarray, round_index: np.ndarray, num_ctrl_pts: int = 10, horizon_s: float = 2.0
) -> FixedSizeArrays:
    """The postprocessing of the C++ collector's records, with world_seed = the round index."""
    if len(records) == 0:
        raise DatasetError("no records to convert (no round dataset, or none with a wanted partition)")
    arrays = records_to_arrays(records, num_ctrl_pts=num_ctrl_pts, horizon_s=horizon_s)
    return dataclasses.replace(arrays, world_seed=np.asarray(round_index, dtype=np.uint64))


def records_to_npz_arrays(
    records: Sequence[Record], num_ctrl_pts: int = 10, horizon_s: float = 2.0
) -> FixedSizeArrays:
    """Records that were never written, converted as their dataset records would be."""
    if not records:
        raise DatasetError("no records to convert (no round dataset, or none with a wanted partition)")
    try:
        shard = shard_records(records)
    except ImitationError as e:
        raise DatasetError(str(e)) from None
    rounds = np.array([r.round_index for r in records], dtype=np.uint64)
    return shard_records_to_npz_arrays(shard, rounds, num_ctrl_pts, horizon_s)


def convert(
    dirs: Sequence[str | Path],
    out: str | Path,
    num_ctrl_pts: int = 10,
    horizon_s: float = 2.0,
    partitions: Sequence[Partition] = DEFAULT_PARTITIONS,
    stride: int = 1,
) -> tuple[Path, int, dict[str, int]]:
    records, rounds, skipped = select_records(dirs, partitions, stride)
    arrays = shard_records_to_npz_arrays(records, rounds, num_ctrl_pts, horizon_s)
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
    cmd = ["--data", str(npz), "--out", str(ckpt), "--name", "train"]
    for extra in args.extra_data:  # e.g. the behaviour-cloning dataset every round aggregates with
        cmd += ["--data", extra]
    for c in args.config:
        cmd += ["--config", c]
    for kv in args.set:
        cmd += ["--set", kv]
    # Imported here: torch takes seconds to import and the plain conversion needs none of it (a downward
    # import, imitation -> learning; tools/import_cycles.py counts it). Trained in this process: the manager
    # runs this command as the round's training child already.
    from quad_il.learning.train import main as train_main

    code = train_main(cmd)
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
        ap = argparse.ArgumentParser(formatter_class=HelpFormatter, prog="quad_il.imitation.convert train")
        ap.add_argument("--data-dirs", required=True, help="comma-separated round data directories")
        ap.add_argument("--checkpoint-dir", required=True, help="the round's checkpoint directory")
        ap.add_argument("--config", action="append", default=[], help="training config; repeat to layer")
        ap.add_argument("--set", action="append", default=[], help="training override KEY=VALUE; repeat")
        ap.add_argument(
            "--policy-file", default="policy.ts", help="name of the exported policy in CHECKPOINT_DIR"
        )
        ap.add_argument(
            "--num-ctrl-pts", type=int, default=10, help="K, control points of the resampled B-spline"
        )
        ap.add_argument(
            "--horizon-s", type=float, default=2.0, help="time span of the resampled B-spline (s)"
        )
        ap.add_argument("--partitions", default="demo,intervention", help="comma-separated partitions kept")
        ap.add_argument("--stride", type=int, default=1, help="keep every N-th record of each episode")
        ap.add_argument(
            "--keep-dataset",
            action="store_true",
            help="keep checkpoint/dataset.npz after a successful training (else removed: remade on demand)",
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
    ap = argparse.ArgumentParser(
        formatter_class=HelpFormatter, prog="quad_il.imitation.convert", description=__doc__.splitlines()[0]
    )
    ap.add_argument("--data", required=True, help="comma-separated round data directories (datasets)")
    ap.add_argument("--out", required=True, help="output .npz")
    ap.add_argument(
        "--num-ctrl-pts", type=int, default=10, help="K, control points of the resampled B-spline"
    )
    ap.add_argument("--horizon-s", type=float, default=2.0, help="time span of the resampled B-spline (s)")
    ap.add_argument("--partitions", default="demo,intervention", help="comma-separated partitions kept")
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
