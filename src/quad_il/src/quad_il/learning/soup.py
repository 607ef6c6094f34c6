"""Weight averaging of training checkpoints into one exported policy (a "model soup", Wortsman et al. 2022).

Checkpoints fine-tuned from a common parent (the rounds of an imitation-learning run, or a round and an
annealed re-training of it, all started from one set of weights) lie in one basin of the loss, and the average
of their weights is often a better network than any of them. Unlike an ensemble it costs nothing at inference:
the result is one network of the same size, exported as any training run's `policy.ts` (docs/learning.md,
"Weight averaging").

    python -m quad_il.learning.soup --checkpoint runs/a/checkpoints/best.pt \
        --checkpoint runs/b/checkpoints/best.pt --out runs/soup_ab/policy.ts

Every checkpoint must have the same model settings (the `model` section of its config), control points and
horizon; floating-point parameters and buffers (BatchNorm running statistics) are averaged, integer buffers
(BatchNorm's batch counters) are taken from the first checkpoint.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import torch

from quad_il.learning.checkpoint import CheckpointError
from quad_il.learning.config import ModelConfig
from quad_il.learning.export import export_policy_file, seeded_check_inputs
from quad_il.learning.model import Policy
from quad_il.learning.runinfo import software_info
from quad_il.learning.trainer import load_policy_checkpoint
from quad_il.tools.cli import HelpFormatter


class SoupError(ValueError):
    """Checkpoints that cannot be averaged (the message names the checkpoint and the difference)."""


def average_checkpoints(paths: list[str | Path], weights: list[float] | None = None) -> tuple[Policy, dict]:
    """The policy with the (weighted) mean of the checkpoints' weights (eval mode) and the first checkpoint.

    weights: one non-negative number per checkpoint (normalised to sum 1); None = equal weights."""
    if len(paths) < 2:
        raise SoupError(f"weight averaging needs at least 2 checkpoints, got {len(paths)}")
    if weights is None:
        weights = [1.0] * len(paths)
    if len(weights) != len(paths):
        raise SoupError(f"{len(weights)} weights for {len(paths)} checkpoints")
    if any(not w >= 0.0 for w in weights) or sum(weights) <= 0.0:
        raise SoupError(f"weights {weights}: must be >= 0 and not all 0")
    total = float(sum(weights))
    loaded = []
    for p in paths:
        if not Path(p).is_file():
            raise SoupError(f"no such checkpoint file {p}")
        try:
            # Read with weights_only=True: a damaged, foreign or code-carrying file is a CheckpointError.
            loaded.append(load_policy_checkpoint(p))
        except ValueError as e:  # CheckpointError (it names the file) or an invalid stored configuration
            raise SoupError(str(e) if isinstance(e, CheckpointError) else f"{p}: {e}") from None
        except RuntimeError as e:  # weights that do not fit the stored model settings
            raise SoupError(f"{p}: cannot use it as a training checkpoint ({e})") from None
    first_policy, first = loaded[0]
    for p, (_, ckpt) in zip(paths[1:], loaded[1:], strict=True):
        for key in ("num_ctrl_pts", "horizon_s"):
            if ckpt[key] != first[key]:
                raise SoupError(f"{p}: {key} {ckpt[key]} differs from {paths[0]}'s {first[key]}")
        a, b = first["config"]["model"], ckpt["config"]["model"]
        differ = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
        if differ:
            raise SoupError(
                f"{p}: model settings differ from {paths[0]}'s ("
                + "; ".join(f"model.{k}: {a.get(k)} vs {b.get(k)}" for k in differ)
                + ")"
            )
    states = [policy.state_dict() for policy, _ in loaded]
    mean: dict[str, torch.Tensor] = {}
    for name, ref in states[0].items():
        if torch.is_floating_point(ref):
            acc = torch.zeros_like(ref, dtype=torch.float64)
            for w, s in zip(weights, states, strict=True):
                acc += (w / total) * s[name].to(torch.float64)
            mean[name] = acc.to(ref.dtype)
        else:
            mean[name] = ref.clone()
    first_policy.load_state_dict(mean)
    return first_policy.eval(), first


def export_soup(
    paths: list[str | Path], out: str | Path, weights: list[float] | None = None
) -> dict[str, Any]:
    """Average the checkpoints and export the result to `out` (TorchScript with metadata, as a training run's
    policy.ts). Returns the metadata's run section."""
    weights = list(weights) if weights is not None else [1.0] * len(paths)
    policy, first = average_checkpoints(paths, weights)
    model_cfg = ModelConfig.model_validate(first["config"]["model"])
    run = {
        "name": "soup",
        "soup_of": [str(p) for p in paths],
        "soup_weights": weights,
        "loss": first["config"].get("optim", {}).get("loss"),
        "software": software_info(),
    }
    export_policy_file(policy, model_cfg, out, run, seeded_check_inputs(model_cfg, 0))
    return run


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        formatter_class=HelpFormatter,
        prog="python -m quad_il.learning.soup",
        description="Average the weights of training checkpoints (same model settings) into one policy.ts.",
    )
    ap.add_argument(
        "--checkpoint", action="append", required=True, help="a training checkpoint (best.pt); repeat, >= 2"
    )
    ap.add_argument("--weight", action="append", type=float, help="one per --checkpoint (default: equal)")
    ap.add_argument("--out", required=True, help="the exported policy file to write (e.g. runs/x/policy.ts)")
    args = ap.parse_args(argv)
    try:
        export_soup(args.checkpoint, args.out, args.weight)
    except SoupError as e:
        print(f"soup: error: {e}", file=sys.stderr)
        return 2
    print(f"soup: {len(args.checkpoint)} checkpoints -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
