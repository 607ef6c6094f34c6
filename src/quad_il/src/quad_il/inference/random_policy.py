"""A policy exported from a randomly initialised model, for the inference benchmark and tests.

Decision latency does not depend on the weights, so `make bench-inference` times a seeded random policy of the
default model configuration (config/train.yaml) rather than a trained one (docs/inference.md says so).

    python -m quad_il.inference.random_policy --out policy.ts [--config config/train.yaml] [--seed 0]
        [--set model.input_height=128 ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch
from torch import Tensor

from quad_il.learning import export as learning_export
from quad_il.learning.config import ModelConfig, load_config
from quad_il.learning.export import export_torchscript, policy_metadata
from quad_il.learning.model import Policy, build_policy


class PolicyWithForwardNet(Policy):
    """Policy plus the network-only entry `forward_net(depth_x, state_x)` that the inference nodes prefer.

    learning/export.py does not preserve such a method yet (docs/inference.md, "Network entry"); this subclass
    and `export_random_policy(..., forward_net=True)` produce files with it, so both paths are tested.
    """

    @torch.jit.export
    def forward_net(self, depth_x: Tensor, state_x: Tensor) -> Tensor:
        return self.net(depth_x, state_x)


def export_random_policy(
    path: str | Path,
    model_cfg: ModelConfig,
    num_ctrl_pts: int = 10,
    horizon_s: float = 2.0,
    seed: int = 0,
    forward_net: bool = False,
) -> Path:
    """Seeded random weights, exported as training does (checked against the eager model on random inputs)."""
    torch.manual_seed(seed)
    policy = (
        PolicyWithForwardNet(model_cfg, num_ctrl_pts, horizon_s)
        if forward_net
        else build_policy(model_cfg, num_ctrl_pts, horizon_s)
    )
    policy.eval()
    g = torch.Generator().manual_seed(seed + 1)
    b = 2
    check = (
        torch.rand(b, 2 * model_cfg.input_height, 2 * model_cfg.input_width, generator=g) * 12.0,
        torch.rand(b, 3, generator=g) * 10.0,
        torch.rand(b, 3, generator=g),
        torch.nn.functional.normalize(torch.rand(b, 4, generator=g) + 0.1, dim=1),
        torch.rand(b, 3, generator=g) * 20.0,
    )
    meta = policy_metadata(
        policy,
        model_cfg.model_dump(mode="json"),
        {"run": {"name": "random_init", "seed": seed, "trained": False}},
    )
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    preserved = learning_export.PRESERVED
    try:
        if forward_net:
            # The export freezes the module keeping only the methods in PRESERVED: add the network entry.
            learning_export.PRESERVED = [*preserved, "forward_net"]
        export_torchscript(policy, out, meta, check)
    finally:
        learning_export.PRESERVED = preserved
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True)
    ap.add_argument(
        "--config", default=None, help="training config whose model section is used (default: defaults)"
    )
    ap.add_argument("--set", action="append", default=[], help="override, e.g. model.input_height=128")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    cfg = load_config([args.config] if args.config else [], args.set)
    path = export_random_policy(
        args.out, cfg.model, cfg.data.shards.num_ctrl_pts, cfg.data.shards.horizon_s, args.seed
    )
    print(
        f"random-init policy ({cfg.model.variant}, {cfg.model.input_height}x{cfg.model.input_width}): {path}",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
