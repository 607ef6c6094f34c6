#!/usr/bin/env python3
"""The thesis's training comparisons (sections 4.2-4.4) as one command each. Thin entry point.

    python training_only/run_experiment.py loss         --data DATASET [--epochs N] [--set ...]
    python training_only/run_experiment.py scheduler    --data DATASET [--epochs N] [--set ...]
    python training_only/run_experiment.py dataset_size --data DATASET [--data-large DATASET2] [--epochs N]

loss: MSE vs SSE (config/experiments/loss_{mse,sse}.yaml, thesis Figure 4.2); scheduler:
CustomCosineDecayRestarts vs PyTorch's CosineAnnealingWarmRestarts (sched_{custom,pytorch}.yaml, Figure 4.3);
dataset_size: small vs large (data_{small,large}.yaml, Figures 4.4/4.5): with --data-large the two runs train
on the two datasets, otherwise on a quarter vs all of the training episodes of DATASET with the same
validation episodes. Every run uses the same seed and base config (config/train.yaml). Output:
<out>/<experiment>/<run>/ (run directories, docs/learning.md), <out>/<experiment>/comparison.png (training
loss, validation loss, validation MSE in the world frame per epoch) and comparison.md (best/final numbers and
the command). --resume continues unfinished runs.
"""

from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from quad_il.learning.checkpoint import CheckpointError
from quad_il.learning.config import ConfigError, load_config
from quad_il.learning.dataset import DatasetError
from quad_il.learning.plots import plot_run_comparison, read_metrics_csv
from quad_il.learning.trainer import NonFiniteLossError, RunDirError, Trainer
from quad_il.tools.cli import HelpFormatter
from quad_il.tools.repo import repo_root

ROOT = repo_root()

EXPERIMENTS = {
    "loss": ("loss_mse", "loss_sse", "MSE vs SSE loss (thesis Figure 4.2)"),
    "scheduler": ("sched_custom", "sched_pytorch", "custom vs PyTorch scheduler (thesis Figure 4.3)"),
    "dataset_size": ("data_small", "data_large", "small vs large dataset (thesis Figures 4.4/4.5)"),
}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("experiment", choices=sorted(EXPERIMENTS), help="the comparison (see above)")
    ap.add_argument("--data", action="append", required=True, help="dataset path (repeat for several)")
    ap.add_argument(
        "--data-large", action="append", default=[], help="dataset_size: the large dataset's paths"
    )
    ap.add_argument("--config", default=str(ROOT / "config" / "train.yaml"), help="base config")
    ap.add_argument("--out", default="runs/experiments", help="parent directory of the experiment")
    ap.add_argument("--epochs", type=int, help="optim.epochs of both runs (default: the configs')")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override for both runs")
    ap.add_argument("--resume", action="store_true", help="continue runs that already have a checkpoint")
    args = ap.parse_args(argv)
    if args.data_large and args.experiment != "dataset_size":
        ap.error("--data-large is only for the dataset_size experiment")
    names = EXPERIMENTS[args.experiment][:2]
    exp_dir = Path(args.out) / args.experiment
    results = {}
    try:
        for name in names:
            data = args.data_large if (name == "data_large" and args.data_large) else args.data
            overrides = [
                "data.paths=[" + ", ".join(repr(str(Path(p).resolve())) for p in data) + "]",
                f"run.out_dir={str(exp_dir)!r}",
                *args.set,
            ]
            if name == "data_small" and args.data_large:
                overrides.append(
                    "data.train_episode_fraction=1.0"
                )  # two datasets: the small one is used whole
            if args.epochs is not None:
                overrides.append(f"optim.epochs={args.epochs}")
            cfg = load_config([args.config, ROOT / "config" / "experiments" / f"{name}.yaml"], overrides)
            # A run killed before its first checkpoint has only config.yaml: --resume starts it over.
            resume = args.resume and (exp_dir / name / "config.yaml").is_file()
            results[name] = Trainer(cfg, resume=resume, argv=sys.argv if argv is None else argv).fit()
    except (ConfigError, DatasetError, RunDirError, NonFiniteLossError, CheckpointError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    runs = {n: read_metrics_csv(exp_dir / n / "metrics.csv") for n in names}
    title = EXPERIMENTS[args.experiment][2]
    plot_run_comparison(runs, exp_dir / "comparison.png", title)
    command = " ".join(
        shlex.quote(a) for a in (["python", "training_only/run_experiment.py"] + (argv or sys.argv[1:]))
    )
    lines = [
        f"# Experiment: {title}",
        "",
        f"Command: `{command}`",
        "",
        "| run | epochs | final training loss | best validation loss (epoch) "
        "| best validation MSE world (m^2) "
        "| final validation cosine world |",
        "|---|---|---|---|---|---|",
    ]
    for n in names:
        rows = runs[n]
        best = min(rows, key=lambda r: r["val_loss"])
        lines.append(
            f"| {n} | {len(rows)} | {rows[-1]['train_loss']:.5g} "
            f"| {best['val_loss']:.5g} ({int(best['epoch'])}) "
            f"| {min(r['val_mse_world_m2'] for r in rows):.5g} | {rows[-1]['val_cosine_world']:.4f} |"
        )
    lines += ["", "![comparison](comparison.png)", ""]
    (exp_dir / "comparison.md").write_text("\n".join(lines))
    print("\n".join(lines))
    print(f"experiment directory: {exp_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
