r"""Train the policy on collected datasets (behaviour cloning, thesis section 3.9).

    python training_only/train_on_cpp_datasets.py --config config/train.yaml --data DATASET [--data ...] \
        [--config config/experiments/X.yaml] [--set key.sub=value ...] [--name RUN] [--resume]
    python -m quad_il.learning.train ...                                   (the same command)

DATASET: an .npz from cpp_dataset_postprocessing.py, a directory of them, or a shard directory (needs
quad_il.data). The run directory is <run.out_dir>/<run.name> (docs/learning.md). Exit status 2 on a
configuration, dataset, checkpoint or distributed-environment error, 3 on a non-finite loss.

Distributed data parallel (docs/scaling.md): the same command under torchrun, e.g.

    torchrun --standalone --nproc_per_node=2 training_only/train_on_cpp_datasets.py --config ... \
        --set run.num_threads=1

optim.batch_size stays the global batch (divided among the processes); only rank 0 writes the run directory.

Library code trains through `main(argv)` (the command line, in this process) or `train(...)` (typed); it never
runs a script (issue 31).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from quad_il.learning.checkpoint import CheckpointError
from quad_il.learning.config import ConfigError, TrainConfig, load_config
from quad_il.learning.dataset import DatasetError
from quad_il.learning.distributed import SINGLE_PROCESS, DistributedSetupError, init_distributed
from quad_il.learning.trainer import NonFiniteLossError, RunDirError, Trainer, TrainResult, run_dir_of
from quad_il.tools.cli import HelpFormatter

# The errors of a bad input (configuration, dataset, run directory, checkpoint, torchrun environment).
TRAIN_INPUT_ERRORS = (ConfigError, DatasetError, RunDirError, DistributedSetupError, CheckpointError)


class TrainingError(RuntimeError):
    """Training did not finish. `status` is the command's exit status (2: bad input, one of
    TRAIN_INPUT_ERRORS, the cause; 3: a non-finite loss); `rank_tag` names the rank under torchrun."""

    def __init__(self, message: str, status: int, rank_tag: str) -> None:
        super().__init__(message)
        self.status = status
        self.rank_tag = rank_tag


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=HelpFormatter)
    ap.add_argument("--config", action="append", default=[], help="YAML config; repeat to layer (later wins)")
    ap.add_argument(
        "--data",
        action="append",
        default=[],
        help="dataset path; repeat, or separate with commas, for several (sets data.paths)",
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
    return ap


def overrides_of(args: argparse.Namespace) -> list[str]:
    """The `key=value` overrides a parsed command line stands for (--set first, then the shorthand flags)."""
    overrides = list(args.set)
    if args.data:
        # Commas separate paths too: the IL manager's {data_dirs} is a comma-separated list (config/il/).
        paths = [p for item in args.data for p in item.split(",") if p]
        overrides.append("data.paths=[" + ", ".join(repr(str(Path(p).resolve())) for p in paths) + "]")
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
    return overrides


def train(
    configs: Sequence[str | os.PathLike[str]],
    overrides: Sequence[str] = (),
    *,
    resume: bool = False,
    argv: Sequence[str] | None = None,
    environ: Mapping[str, str] | None = None,
) -> TrainResult | None:
    """Load the layered config, join torchrun's process group if there is one, and train.

    Returns the result on rank 0 (and in a single process), None on the other ranks; raises TrainingError.
    `argv` is recorded in the run's manifest (default sys.argv).
    """
    overrides = list(overrides)
    ctx = SINGLE_PROCESS
    try:
        cfg = load_config(list(configs), overrides)
        # Under torchrun: check the environment and join the process group (a single process otherwise).
        ctx = init_distributed(cfg, os.environ if environ is None else environ)

        def resolve() -> TrainConfig:
            saved = run_dir_of(cfg) / "config.yaml"
            if resume and saved.is_file():
                # Resume from the run's own configuration; this command's overrides (e.g. --epochs) apply.
                return load_config([saved], overrides)
            return cfg

        # Rank 0 resolves (it alone reads the run directory) and every rank trains with its answer.
        cfg = ctx.run_on_main(resolve)
        result = Trainer(cfg, resume=resume, argv=list(sys.argv if argv is None else argv), dist=ctx).fit()
    except TRAIN_INPUT_ERRORS as e:
        raise TrainingError(str(e), 2, ctx.tag) from e
    except NonFiniteLossError as e:
        raise TrainingError(f"training stopped: {e}", 3, ctx.tag) from e
    finally:
        ctx.close()
    return result if ctx.is_main else None


def main(argv: Sequence[str] | None = None, environ: Mapping[str, str] | None = None) -> int:
    """The command line above; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        result = train(
            args.config,
            overrides_of(args),
            resume=args.resume,
            argv=sys.argv if argv is None else list(argv),
            environ=environ,
        )
    except TrainingError as e:
        print(f"error{e.rank_tag}: {e}", file=sys.stderr)
        return e.status
    if result is None:
        return 0
    print(f"run directory: {result.run_dir}")
    print(f"best epoch {result.best_epoch}: validation loss {result.best_val_loss:.6g}")
    if result.policy_path is not None:
        print(f"policy: {result.policy_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
