#!/usr/bin/env python3
"""Train the policy on collected datasets (behaviour cloning, thesis section 3.9). Thin entry point.

    python training_only/train_on_cpp_datasets.py --config config/train.yaml --data DATASET [--data ...] \
        [--config config/experiments/X.yaml] [--set key.sub=value ...] [--name RUN] [--resume]

DATASET: an .npz from cpp_dataset_postprocessing.py, a directory of them, or a shard directory (needs
quad_il.data). The run directory is <run.out_dir>/<run.name> (docs/learning.md). Exit status 2 on a
configuration or dataset error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src" / "quad_il" / "src"))

from quad_il.learning.config import ConfigError, load_config  # noqa: E402
from quad_il.learning.dataset import DatasetError  # noqa: E402
from quad_il.learning.trainer import NonFiniteLossError, RunDirError, Trainer, run_dir_of  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--config", action="append", default=[], help="YAML config; repeat to layer (later wins)")
    ap.add_argument(
        "--data", action="append", default=[], help="dataset path; repeat for several (sets data.paths)"
    )
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override, e.g. optim.lr=1e-3"
    )
    ap.add_argument("--name", help="run name (run.name)")
    ap.add_argument("--out", help="parent directory of runs (run.out_dir)")
    ap.add_argument("--epochs", type=int, help="optim.epochs")
    ap.add_argument("--seed", type=int, help="run.seed")
    ap.add_argument(
        "--resume",
        action="store_true",
        help="continue <out>/<name> from checkpoints/last.pt (its own config.yaml plus these overrides)",
    )
    args = ap.parse_args(argv)
    overrides = list(args.set)
    if args.data:
        overrides.append("data.paths=[" + ", ".join(repr(str(Path(p).resolve())) for p in args.data) + "]")
    for flag, key in (
        ("name", "run.name"),
        ("out", "run.out_dir"),
        ("epochs", "optim.epochs"),
        ("seed", "run.seed"),
    ):
        value = getattr(args, flag)
        if value is not None:
            overrides.append(f"{key}={value!r}" if isinstance(value, str) else f"{key}={value}")
    try:
        cfg = load_config(args.config, overrides)
        saved = run_dir_of(cfg) / "config.yaml"
        if args.resume and saved.is_file():
            # Resume from the run's own configuration; this command's overrides (e.g. --epochs) apply on top.
            cfg = load_config([saved], overrides)
        result = Trainer(cfg, resume=args.resume, argv=sys.argv if argv is None else argv).fit()
    except (ConfigError, DatasetError, RunDirError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except NonFiniteLossError as e:
        print(f"error: training stopped: {e}", file=sys.stderr)
        return 3
    print(f"run directory: {result.run_dir}")
    print(f"best epoch {result.best_epoch}: validation loss {result.best_val_loss:.6g}")
    if result.policy_path is not None:
        print(f"policy: {result.policy_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
