"""A policy exported from a randomly initialised model, for the inference benchmark and tests; and
goal-seeking test doubles with the same file interface (`export_goal_line_policy`, and
`export_goal_fan_policy` with several hypotheses).

Decision latency does not depend on the weights, so `make bench-inference` times a seeded random policy of the
default model configuration (config/train.yaml) rather than a trained one (docs/inference.md says so).

    python -m quad_il.inference.random_policy --out policy.ts [--config config/train.yaml] [--seed 0]
        [--set model.input_height=128 ...]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import torch
from torch import Tensor

from quad_il.learning import export as learning_export
from quad_il.learning.config import ModelConfig, load_config
from quad_il.learning.export import export_policy_file, seeded_check_inputs
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
    check = seeded_check_inputs(model_cfg, seed + 1)
    preserved = learning_export.PRESERVED
    try:
        if forward_net:
            # The export freezes the module keeping only the methods in PRESERVED: add the network entry.
            learning_export.PRESERVED = [*preserved, "forward_net"]
        return export_policy_file(
            policy, model_cfg, path, {"name": "random_init", "seed": seed, "trained": False}, check
        )
    finally:
        learning_export.PRESERVED = preserved


class GoalLinePolicy(Policy):
    """Test double in the exported-policy format whose "network" ignores the depth image: a straight line from
    the vehicle toward the goal at `speed_mps` (control points (i - 1) dt speed along the goal direction),
    encoded like a trained output. Both nodes decode and judge it as they would a trained policy's, so tests
    can build scenes where turned goals are refused or accepted (recovery, steering) in C++ and Python."""

    def __init__(self, model_cfg: ModelConfig, num_ctrl_pts: int, horizon_s: float, speed_mps: float) -> None:
        super().__init__(model_cfg, num_ctrl_pts, horizon_s)
        self.speed_mps = float(speed_mps)

    def goal_line(self, p_world_body: Tensor, goal_world: Tensor) -> Tensor:
        """(B, K, 3) world-frame control points of the straight line at the goal (subclasses reuse it)."""
        k = self.num_ctrl_pts
        dt = self.horizon_s / (k - 3)
        d = goal_world - p_world_body
        direction = d / torch.linalg.norm(d, dim=1, keepdim=True).clamp_min(1e-9)
        tau = (torch.arange(k, dtype=p_world_body.dtype, device=p_world_body.device) - 1.0) * dt
        return p_world_body.unsqueeze(1) + self.speed_mps * tau.view(1, k, 1) * direction.unsqueeze(1)

    @torch.jit.export
    def forward_prepared(
        self, depth_x: Tensor, p_world_body: Tensor, v_world: Tensor, q_world_body: Tensor, goal_world: Tensor
    ) -> Tensor:
        return self.codec.encode(self.goal_line(p_world_body, goal_world), p_world_body, q_world_body)


def export_goal_line_policy(
    path: str | Path, num_ctrl_pts: int = 10, horizon_s: float = 2.0, speed_mps: float = 1.5
) -> Path:
    """GoalLinePolicy (world-frame B-spline output, 32 x 32 input) exported as training does."""
    model_cfg = ModelConfig(input_height=32, input_width=32)
    torch.manual_seed(0)
    policy = GoalLinePolicy(model_cfg, num_ctrl_pts, horizon_s, speed_mps).eval()
    check = seeded_check_inputs(model_cfg, 1, goal_offset_m=11.0)  # goals never at the vehicle
    run = {"name": "goal_line_test_double", "speed_mps": speed_mps, "trained": False}
    return export_policy_file(policy, model_cfg, path, run, check)


class GoalFanPolicy(GoalLinePolicy):
    """Test double with several hypotheses (model.hypotheses = len(yaws_deg)): straight lines at `speed_mps`
    towards the goal turned about the vehicle by each of `yaws_deg` (+ = left), with fixed confidence logits,
    so tests can build scenes where the most confident plan is refused and another hypothesis is accepted in
    C++ and Python alike."""

    def __init__(
        self,
        model_cfg: ModelConfig,
        num_ctrl_pts: int,
        horizon_s: float,
        speed_mps: float,
        yaws_deg: list[float],
        logits: list[float],
    ) -> None:
        if len(yaws_deg) != model_cfg.hypotheses or len(logits) != model_cfg.hypotheses:
            raise ValueError(
                f"GoalFanPolicy: {model_cfg.hypotheses} hypotheses need as many yaws and logits, got "
                f"{len(yaws_deg)} and {len(logits)}"
            )
        super().__init__(model_cfg, num_ctrl_pts, horizon_s, speed_mps)
        self.cos_yaw = [math.cos(math.radians(a)) for a in yaws_deg]
        self.sin_yaw = [math.sin(math.radians(a)) for a in yaws_deg]
        self.register_buffer("fan_logits", torch.tensor(logits, dtype=torch.float32))

    @torch.jit.export
    def forward_prepared(
        self, depth_x: Tensor, p_world_body: Tensor, v_world: Tensor, q_world_body: Tensor, goal_world: Tensor
    ) -> Tensor:
        d = goal_world - p_world_body
        parts: list[Tensor] = []
        for i in range(len(self.cos_yaw)):
            c, s = self.cos_yaw[i], self.sin_yaw[i]
            turned = torch.stack([c * d[:, 0] - s * d[:, 1], s * d[:, 0] + c * d[:, 1], d[:, 2]], dim=1)
            line = self.goal_line(p_world_body, p_world_body + turned)
            parts.append(self.codec.encode(line, p_world_body, q_world_body))
        parts.append(self.fan_logits.unsqueeze(0).expand(p_world_body.size(0), -1))
        return torch.cat(parts, dim=1)


def export_goal_fan_policy(
    path: str | Path,
    yaws_deg: list[float],
    logits: list[float],
    num_ctrl_pts: int = 10,
    horizon_s: float = 2.0,
    speed_mps: float = 1.5,
) -> Path:
    """GoalFanPolicy (world-frame B-spline output, 32 x 32 input) exported as training does."""
    model_cfg = ModelConfig(input_height=32, input_width=32, hypotheses=len(yaws_deg))
    torch.manual_seed(0)
    policy = GoalFanPolicy(model_cfg, num_ctrl_pts, horizon_s, speed_mps, yaws_deg, logits).eval()
    check = seeded_check_inputs(model_cfg, 1, goal_offset_m=11.0)  # goals never at the vehicle
    run = {"name": "goal_fan_test_double", "yaws_deg": yaws_deg, "logits": logits, "trained": False}
    return export_policy_file(policy, model_cfg, path, run, check)


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
