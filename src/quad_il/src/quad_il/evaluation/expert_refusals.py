"""The safety layer's verdicts on the expert's own plans (issue 33): how often the checks that judge a
policy's proposals would refuse the plans the policy is trained to imitate, on the frames they were made at.

    python -m quad_il.evaluation.expert_refusals --data data/train [--policy-config config/policy.yaml]
        [--train-config config/train.yaml] [--sim-config config/sim.yaml] [--max-records 20000] [--out F.json]

Every record of the datasets (an expert plan with the depth frame and the odometry it was made from) becomes
what a perfect imitation would propose there: the plan resampled to the network's output (the training
target: `data.shards` num_ctrl_pts over horizon_s from the frame's stamp, quad_il.data.postprocess), in the
world frame, judged by quad_policy's CheckTrajectory (the C++ safety layer both policy nodes run, bound) with
the policy config's `safety` checks, the frame's depth in float32 metres and the camera at the frame's
odometry (T_world_body T_body_camera of the sim config's mount). A policy's refusal rate (the verdict counts
of an evaluation, docs/inference.md) is read against this one: a check that refuses many expert plans is too
strict. Prints the verdicts with 95 % Wilson intervals; --out writes them as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from quad_il.data.format import DatasetError, depth_lut
from quad_il.data.postprocess import ResampleConfig, records_to_arrays
from quad_il.data.shards import open_dataset
from quad_il.evaluation.stats import format_rate
from quad_il.inference.config import load_policy_config
from quad_il.inference.core import CameraModel, UniformBspline, check_trajectory
from quad_il.learning.config import load_config
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_root


class ExpertRefusalError(ValueError):
    """Bad input of the tool; the message names the path or argument."""


@dataclass
class RefusalTally:
    records: int = 0
    verdicts: dict[str, int] = field(default_factory=dict)
    # The first refusal of each kind: "<shard file> record <index in the shard>: <reason>", to look at.
    examples: dict[str, str] = field(default_factory=dict)

    @property
    def refused(self) -> int:
        return self.records - self.verdicts.get("accepted", 0)


def _camera_mount(sim_config: Path) -> np.ndarray:
    from quad_il.engine import native

    return np.asarray(native().sim_camera_mount(str(sim_config)), dtype=np.float64)


def judge_dataset(
    path: Path,
    safety,
    resample: ResampleConfig,
    T_body_camera: np.ndarray,
    tally: RefusalTally,
    max_records: int = 0,
    progress: tqdm | None = None,
) -> None:
    """Adds the verdicts of the dataset's valid records (up to max_records in all) to `tally`."""
    ds = open_dataset(path)
    h = ds.header
    if h is None:
        return
    if not (h.camera_fx_px > 0 and h.camera_fy_px > 0):
        raise ExpertRefusalError(f"{path}: the dataset's header has no camera intrinsics (fx, fy = 0)")
    lut = depth_lut("float32")
    for shard, records, indices in ds.valid_record_arrays():
        for start in range(0, len(records), 256):
            if max_records and tally.records >= max_records:
                return
            chunk = records[start : start + 256]
            if max_records:
                chunk = chunk[: max_records - tally.records]
            fixed = records_to_arrays(chunk, num_ctrl_pts=resample.num_ctrl_pts, horizon_s=resample.horizon_s)
            for j in range(len(chunk)):
                p = fixed.p_world_body[j].astype(np.float64)
                T_world_body = np.eye(4)
                T_world_body[:3, :3] = Rotation.from_quat(
                    fixed.q_world_body[j].astype(np.float64)
                ).as_matrix()
                T_world_body[:3, 3] = p
                camera = CameraModel(
                    int(h.image_width),
                    int(h.image_height),
                    h.camera_fx_px,
                    h.camera_fy_px,
                    h.camera_cx_px,
                    h.camera_cy_px,
                    T_world_body @ T_body_camera,
                )
                plan = UniformBspline(
                    start_time_s=float(fixed.depth_stamp_s[j]),
                    knot_dt_s=resample.knot_dt_s,
                    ctrl_world=fixed.bspline_ctrl_world[j].astype(np.float64),
                )
                depth = lut[chunk["depth_code"][j]]
                result = check_trajectory(plan, p, depth, camera, safety)
                tally.records += 1
                tally.verdicts[result.label] = tally.verdicts.get(result.label, 0) + 1
                if not result.accepted and result.label not in tally.examples:
                    where = f"{path / shard.name} record {int(indices[start + j])}"
                    tally.examples[result.label] = f"{where}: {result.reason}"
            if progress is not None:
                progress.update(len(chunk))


def format_tally(tally: RefusalTally) -> str:
    lines = [
        f"expert plans judged by the safety layer: {tally.records}",
        f"  refused: {tally.refused} = {format_rate(tally.refused, tally.records)}",
    ]
    for label, n in sorted(tally.verdicts.items(), key=lambda kv: -kv[1]):
        lines.append(f"  {label}: {n} = {format_rate(n, tally.records)}")
    for label, where in sorted(tally.examples.items()):
        lines.append(f"  first {label}: {where}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m quad_il.evaluation.expert_refusals",
        description=__doc__.split("\n\n")[0],
        formatter_class=HelpFormatter,
    )
    ap.add_argument("--data", required=True, help="dataset directories, comma-separated")
    ap.add_argument(
        "--policy-config", default="config/policy.yaml", help="its `safety` checks judge the plans"
    )
    ap.add_argument(
        "--train-config", default="config/train.yaml", help="its data.shards: the network's output"
    )
    ap.add_argument("--sim-config", default="config/sim.yaml", help="the camera mount")
    ap.add_argument("--max-records", type=int, default=0, help="judge at most this many records (0: all)")
    ap.add_argument("--out", default="", help="write the tally as JSON here")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    return ap


def _path(root: Path, text: str) -> Path:
    p = Path(text)
    return p if p.is_absolute() else root / p


def main(argv: Sequence[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    root = repo_root()
    if args.max_records < 0:
        ap.error(f"--max-records {args.max_records}: must be >= 0")
    datasets = [Path(d) for d in args.data.split(",") if d.strip()]
    for d in datasets:
        if not d.is_dir():
            ap.error(f"--data {d}: no such directory")
    cfgs = {k: _path(root, getattr(args, k)) for k in ("policy_config", "train_config", "sim_config")}
    for k, p in cfgs.items():
        if not p.is_file():
            ap.error(f"--{k.replace('_', '-')} {p}: no such file")
    try:
        safety = load_policy_config(cfgs["policy_config"]).safety
        shards = load_config([cfgs["train_config"]]).data.shards
        resample = ResampleConfig(num_ctrl_pts=shards.num_ctrl_pts, horizon_s=shards.horizon_s)
        T_body_camera = _camera_mount(cfgs["sim_config"])
    except (ValueError, RuntimeError) as e:  # the loaders' errors name the file and key
        print(f"expert_refusals: {e}", file=sys.stderr)
        return 2
    tally = RefusalTally()
    try:
        total = sum(len(open_dataset(d)) for d in datasets)
        if args.max_records:
            total = min(total, args.max_records)
        with tqdm(total=total, unit="plan", desc="judge", disable=args.no_progress) as bar:
            for d in datasets:
                judge_dataset(d, safety, resample, T_body_camera, tally, args.max_records, bar)
    except (ExpertRefusalError, DatasetError) as e:
        print(f"expert_refusals: {e}", file=sys.stderr)
        return 2
    print(format_tally(tally))
    if args.out:
        Path(args.out).write_text(
            json.dumps(
                {**asdict(tally), "refused": tally.refused, "policy_config": str(cfgs["policy_config"])},
                indent=2,
            )
            + "\n"
        )
    return 0 if tally.records else 1


if __name__ == "__main__":
    sys.exit(main())
