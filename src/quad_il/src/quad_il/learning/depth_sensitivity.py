"""How much does a trained policy's plan depend on its depth image? (docs/learning.md; measured in
docs/notebook/2026-12_closed_loop_issue8.md, "How much does the network look at the depth image?")

For held-out samples: the plan with the recorded depth frame, with an empty view (every pixel "no return",
+inf) and with another sample's frame, against the expert's plan. A policy that ignores depth gives the same
plan for all three frames; the expert's departure from the policy's empty-view plan shows how much the scene
should bend the plan.

    python -m quad_il.learning.depth_sensitivity --policy runs/X/policy.ts --data data/heldout_s5000 \
        [--samples 800] [--seed 0]

Prints a Markdown table; exit status 2 on a bad policy or dataset.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from numpy.typing import NDArray

from quad_il.learning.dataset import DEFAULT_SHARD_OPTIONS, DatasetError, expand_paths, read_source
from quad_il.learning.evaluation import load_policy
from quad_il.tools.cli import HelpFormatter

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class DepthSensitivity:
    samples: int
    rms_policy_expert_m: float  # RMS control-point distance, policy (recorded frame) vs expert
    rms_real_vs_empty_m: float  # the policy with the recorded frame vs with an empty view
    rms_real_vs_other_m: float  # the policy with the recorded frame vs with another sample's frame
    end_dir_expert_vs_empty_deg: float  # median |end direction| difference, expert vs the empty-view plan
    end_dir_real_vs_empty_deg: float  # the same, policy with the recorded frame vs with an empty view


def rms_distance(a: FloatArray, b: FloatArray) -> float:
    """Root mean square over samples and control points of the distance between matching control points."""
    return float(np.sqrt(((a - b) ** 2).sum(-1).mean()))


def end_direction_deg(ctrl: FloatArray) -> FloatArray:
    """Horizontal direction (deg) from the first to the last control point of each (N, K, 3) plan."""
    d = ctrl[:, -1, :2] - ctrl[:, 0, :2]
    return np.degrees(np.arctan2(d[:, 1], d[:, 0]))


def angle_diff_deg(a: FloatArray, b: FloatArray) -> FloatArray:
    return np.abs((a - b + 180.0) % 360.0 - 180.0)


def measure(
    policy_path: str | Path, data: Sequence[str | Path], samples: int = 800, seed: int = 0
) -> DepthSensitivity:
    policy = load_policy(policy_path)
    arrays: dict[str, list[np.ndarray]] = {}
    keys = ("depth_m", "p_world_body", "v_world", "q_world_body", "goal_world", "bspline_ctrl_world")
    for path, kind in expand_paths(data):
        a = read_source(path, kind, DEFAULT_SHARD_OPTIONS)
        for k in keys:
            arrays.setdefault(k, []).append(np.asarray(a[k]))
    n_all = sum(len(x) for x in arrays["depth_m"])
    if n_all < 2:
        raise DatasetError(f"{', '.join(str(d) for d in data)}: need at least 2 samples, found {n_all}")
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(n_all, min(samples, n_all), replace=False))
    cat = {k: np.concatenate(v)[idx] for k, v in arrays.items()}
    other = rng.permutation(len(idx))
    other = np.where(other == np.arange(len(idx)), np.roll(other, 1), other)  # never the sample's own frame

    def run(depth: np.ndarray) -> FloatArray:
        out = []
        for s in range(0, len(idx), 64):
            b = {k: torch.from_numpy(np.asarray(v[s : s + 64], dtype=np.float32)) for k, v in cat.items()}
            with torch.no_grad():
                d = torch.from_numpy(np.asarray(depth[s : s + 64], dtype=np.float32))
                out.append(policy.fn(d, b["p_world_body"], b["v_world"], b["q_world_body"], b["goal_world"]))
        return torch.cat(out).double().numpy()

    real = run(cat["depth_m"])
    empty = run(np.full_like(cat["depth_m"], np.inf))
    swapped = run(cat["depth_m"][other])
    expert = cat["bspline_ctrl_world"].astype(np.float64)
    return DepthSensitivity(
        samples=len(idx),
        rms_policy_expert_m=rms_distance(real, expert),
        rms_real_vs_empty_m=rms_distance(real, empty),
        rms_real_vs_other_m=rms_distance(real, swapped),
        end_dir_expert_vs_empty_deg=float(
            np.median(angle_diff_deg(end_direction_deg(expert), end_direction_deg(empty)))
        ),
        end_dir_real_vs_empty_deg=float(
            np.median(angle_diff_deg(end_direction_deg(real), end_direction_deg(empty)))
        ),
    )


def markdown(r: DepthSensitivity) -> str:
    rows = [
        ("RMS control-point distance, policy vs expert", f"{r.rms_policy_expert_m:.2f} m"),
        (
            "RMS control-point distance, policy with the real frame vs with an empty view",
            f"{r.rms_real_vs_empty_m:.2f} m",
        ),
        ("the same with another sample's frame", f"{r.rms_real_vs_other_m:.2f} m"),
        (
            "end direction, expert vs the policy's empty-view plan (median)",
            f"{r.end_dir_expert_vs_empty_deg:.1f} deg",
        ),
        (
            "end direction, policy with the real frame vs with an empty view (median)",
            f"{r.end_dir_real_vs_empty_deg:.1f} deg",
        ),
    ]
    lines = [f"| quantity ({r.samples} samples) | value |", "|---|---|"]
    return "\n".join(lines + [f"| {a} | {b} |" for a, b in rows])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument(
        "--policy", required=True, help="exported policy (.ts), run directory or checkpoint (.pt)"
    )
    ap.add_argument(
        "--data", required=True, action="append", help="held-out dataset (npz or shard directory)"
    )
    ap.add_argument("--samples", type=int, default=800, help="held-out samples drawn")
    ap.add_argument("--seed", type=int, default=0, help="seed of the sample draw and the frame swap")
    args = ap.parse_args(argv)
    if args.samples < 2:
        print("depth_sensitivity: --samples must be at least 2", file=sys.stderr)
        return 2
    try:
        if not Path(args.policy).exists():
            raise FileNotFoundError(f"--policy: no such file or directory {args.policy!r}")
        print(markdown(measure(args.policy, args.data, args.samples, args.seed)))
    except (DatasetError, FileNotFoundError, ValueError) as e:
        print(f"depth_sensitivity: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
