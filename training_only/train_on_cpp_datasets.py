#!/usr/bin/env python3
"""Train the policy on collected datasets (behaviour cloning, thesis section 3.9). Thin entry point.

    python training_only/train_on_cpp_datasets.py --config config/train.yaml --data DATASET [--data ...] \
        [--config config/experiments/X.yaml] [--set key.sub=value ...] [--name RUN] [--resume]

DATASET: an .npz from cpp_dataset_postprocessing.py, a directory of them, or a shard directory (needs
quad_il.data). The run directory is <run.out_dir>/<run.name> (docs/learning.md). Exit status 2 on a
configuration, dataset, checkpoint or distributed-environment error, 3 on a non-finite loss.

Distributed data parallel (docs/scaling.md): the same command under torchrun, e.g.

    torchrun --standalone --nproc_per_node=2 training_only/train_on_cpp_datasets.py --config ... \
        --set run.num_threads=1

optim.batch_size stays the global batch (divided among the processes); only rank 0 writes the run directory.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Mapping
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src" / "quad_il" / "src"))

from quad_il.learning.checkpoint import CheckpointError  # noqa: E402
from quad_il.learning.config import ConfigError, load_config  # noqa: E402
from quad_il.learning.dataset import DatasetError  # noqa: E402
from quad_il.learning.distributed import (  # noqa: E402
    SINGLE_PROCESS,
    DistributedSetupError,
    init_distributed,
)
from quad_il.learning.trainer import NonFiniteLossError, RunDirError, Trainer, run_dir_of  # noqa: E402


def main(argv: list[str] | None = None, environ: Mapping[str, str] | None = None) -> int:
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
    ap.add_argument(
        "--dist-backend",
        choices=["auto", "gloo", "nccl"],
        help="dist.backend under torchrun (auto: nccl with CUDA, else gloo)",
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
        ("dist_backend", "dist.backend"),
    ):
        value = getattr(args, flag)
        if value is not None:
            overrides.append(f"{key}={value!r}" if isinstance(value, str) else f"{key}={value}")
    ctx = SINGLE_PROCESS
    try:
        cfg = load_config(args.config, overrides)
        # Under torchrun: check the environment and join the process group (a single process otherwise).
        ctx = init_distributed(cfg, os.environ if environ is None else environ)

        def resolve() -> object:
            saved = run_dir_of(cfg) / "config.yaml"
            if args.resume and saved.is_file():
                # Resume from the run's own configuration; this command's overrides (e.g. --epochs) apply.
                return load_config([saved], overrides)
            return cfg

        # Rank 0 resolves (it alone reads the run directory) and every rank trains with its answer.
        cfg = ctx.run_on_main(resolve)  # type: ignore[assignment]
        result = Trainer(cfg, resume=args.resume, argv=sys.argv if argv is None else argv, dist=ctx).fit()
    except (ConfigError, DatasetError, RunDirError, DistributedSetupError, CheckpointError) as e:
        print(f"error{ctx.tag}: {e}", file=sys.stderr)
        return 2
    except NonFiniteLossError as e:
        print(f"error{ctx.tag}: training stopped: {e}", file=sys.stderr)
        return 3
    finally:
        ctx.close()
    if not ctx.is_main:
        return 0
    print(f"run directory: {result.run_dir}")
    print(f"best epoch {result.best_epoch}: validation loss {result.best_val_loss:.6g}")
    if result.policy_path is not None:
        print(f"policy: {result.policy_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
