#!/usr/bin/env python3
"""Offline evaluation of a trained policy on held-out data (thesis section 4.5). Thin entry point.

    python training_only/evaluate_policy.py --policy RUN_DIR|policy.ts|checkpoint.pt \
        --data HELDOUT [--data ...] --out DIR [--bhattacharyya-reg-m2 0.01] [--figure-seed 0] \
        [--allow-seen-worlds]

Writes per_sample.csv, summary.md (mean with 95 % CI), summary.json and the 12-panel figures to DIR
(docs/learning.md). Refuses data from worlds the policy was trained on unless --allow-seen-worlds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from quad_il.learning.dataset import DatasetError
from quad_il.learning.evaluation import evaluate
from quad_il.learning.metrics import DEFAULT_BHATTACHARYYA_REG_M2
from quad_il.tools.cli import HelpFormatter


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--policy", required=True, help="run directory, exported policy.ts or checkpoint .pt")
    ap.add_argument(
        "--data", action="append", required=True, help="held-out dataset path; repeat for several"
    )
    ap.add_argument("--out", required=True, help="output directory")
    ap.add_argument(
        "--bhattacharyya-reg-m2",
        type=float,
        default=DEFAULT_BHATTACHARYYA_REG_M2,
        help="covariance regulariser (m^2)",
    )
    ap.add_argument("--batch-size", type=int, default=64, help="inference batch size")
    ap.add_argument("--figure-seed", type=int, default=0, help="seed choosing the 12 samples of the figure")
    ap.add_argument("--threads", type=int, default=2, help="torch threads")
    ap.add_argument(
        "--allow-seen-worlds", action="store_true", help="evaluate even on worlds used in training"
    )
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(args.threads)
    try:
        summary = evaluate(
            args.policy,
            args.data,
            args.out,
            args.bhattacharyya_reg_m2,
            args.batch_size,
            args.figure_seed,
            args.allow_seen_worlds,
        )
    except (DatasetError, ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print((Path(args.out) / "summary.md").read_text())
    print(f"{summary['num_samples']} samples evaluated; report in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
