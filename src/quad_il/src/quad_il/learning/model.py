"""The policy network of the thesis (section 3.7, Table 3.1) and the exported policy around it.

    depth (B,1,h,w) -> MobileNetV3 (1000 logits) -> post-processing MLP [128, 64, 32] --+
                                                                                       concat
    state (B,13) -> state MLP [64, 32, 32] --------------------------------------------+
        -> planning MLP [64, 128, 128] -> Linear -> flat B-spline (K x 3) or polynomial coefficients
        (+ optionally a fixed linear map of the state: model.output_prior = constant_velocity)

    optionally (model.depth_grid = [r, c]): depth -> max-pooled nearness on an r x c grid -> flattened, a
    third input of the planning MLP (the nearest surface in each cell, not to be learnt from pixels)

    optionally (model.hypotheses = M > 1): the final Linear gives M plans and M confidence logits,
    [plan_0 (D), ..., plan_{M-1} (D), logit_0, ..., logit_{M-1}], trained winner-takes-all (losses.py); the
    plan flown is the one with the largest logit (`Policy.select`), or plan 0, a plain regression, with
    model.hypotheses_first = mean; the others are alternatives for the inference nodes' safety layer
    (docs/learning.md, "Multiple hypotheses")

ReLU after every hidden layer of the three MLPs (the thesis: "All networks use ReLU"); the final Linear has
none.

`Policy` wraps the network with the preprocessing and output decoding of `preprocessing.py`, so one
TorchScript file maps (raw depth metres, odometry, goal) to world-frame control points (`export.py`).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from quad_il.learning.checkpoint import read_checkpoint_file
from quad_il.learning.config import ModelConfig
from quad_il.learning.mobilenet_v3 import MobileNetV3
from quad_il.learning.preprocessing import (
    STATE_DIM,
    DepthPreprocessor,
    OutputCodec,
    StateEncoder,
    constant_velocity_prior,
)


def mlp(in_dim: int, widths: Sequence[int]) -> nn.Sequential:
    """Linear -> ReLU for each width."""
    layers: list[nn.Module] = []
    for w in widths:
        layers += [nn.Linear(in_dim, w), nn.ReLU()]
        in_dim = w
    return nn.Sequential(*layers)


class PolicyNet(nn.Module):
    """The learned part: (preprocessed depth, state vector) -> flat output vector."""

    def __init__(
        self,
        variant: str,
        out_dim: int,
        backbone_out: int = 1000,
        backbone_dropout: float = 0.2,
        depth_mlp: Sequence[int] = (128, 64, 32),
        state_mlp: Sequence[int] = (64, 32, 32),
        planning_mlp: Sequence[int] = (64, 128, 128),
        state_dim: int = STATE_DIM,
        prior: Tensor | None = None,
        depth_grid: Sequence[int] = (),
        hypotheses: int = 1,
    ) -> None:
        super().__init__()
        if int(hypotheses) < 1:
            raise ValueError(f"hypotheses must be >= 1, got {hypotheses}")
        if len(depth_grid) not in (0, 2) or any(int(n) < 1 for n in depth_grid):
            raise ValueError(f"depth_grid must be () or (rows, cols) >= 1, got {tuple(depth_grid)}")
        # Top-level ints (not a tuple) so TorchScript sees a plain, constant-size grid.
        self.grid_rows = int(depth_grid[0]) if depth_grid else 0
        self.grid_cols = int(depth_grid[1]) if depth_grid else 0
        self.backbone = MobileNetV3(
            variant, in_channels=1, num_classes=backbone_out, dropout=backbone_dropout
        )
        self.depth_mlp = mlp(backbone_out, depth_mlp)
        self.state_mlp = mlp(state_dim, state_mlp)
        grid_dim = self.grid_rows * self.grid_cols
        self.planning_mlp = mlp(depth_mlp[-1] + state_mlp[-1] + grid_dim, planning_mlp)
        self.hypotheses = int(hypotheses)
        self.plan_dim = int(out_dim)
        total = head_output_dim(out_dim, self.hypotheses)
        self.head = nn.Linear(planning_mlp[-1], total)
        for m in [self.depth_mlp, self.state_mlp, self.planning_mlp, self.head]:
            for layer in m.modules():
                if isinstance(layer, nn.Linear):
                    # PyTorch's default Linear init (Kaiming-uniform a=sqrt(5)); explicit so it is seeded
                    # here.
                    layer.reset_parameters()
        # Fixed linear map of the state added to the head's output (model.output_prior; zeros for none): the
        # same for every hypothesis, none for the confidence logits. Not persistent: it follows from the
        # configuration, so checkpoints from before it still load.
        if prior is None:
            prior = torch.zeros(out_dim, state_dim)
        if tuple(prior.shape) != (out_dim, state_dim):
            raise ValueError(f"prior must be ({out_dim}, {state_dim}), got {tuple(prior.shape)}")
        if self.hypotheses > 1:
            prior = torch.cat([prior.repeat(self.hypotheses, 1), torch.zeros(self.hypotheses, state_dim)])
        self.register_buffer("prior", prior.to(torch.float32), persistent=False)

    def forward(self, depth_x: Tensor, state_x: Tensor) -> Tensor:
        f_depth = self.depth_mlp(self.backbone(depth_x))
        f_state = self.state_mlp(state_x)
        if self.grid_rows > 0:
            feats = torch.cat([f_depth, f_state, self.grid_features(depth_x)], dim=1)
        else:
            feats = torch.cat([f_depth, f_state], dim=1)
        y = self.head(self.planning_mlp(feats))
        return y + torch.matmul(state_x, self.prior.t())

    def grid_features(self, depth_x: Tensor) -> Tensor:
        """(B,1,h,w) preprocessed depth in [0, 1] -> (B, rows*cols): per cell, 1 - the smallest depth (0 = all
        at max_depth_m or beyond, 1 = a surface at the camera). Row-major, image rows top to bottom."""
        near = F.adaptive_max_pool2d(1.0 - depth_x, [self.grid_rows, self.grid_cols])
        return near.flatten(1)


def head_output_dim(plan_dim: int, hypotheses: int) -> int:
    """Width of the network's flat output: one plan, or M plans and their M confidence logits."""
    return plan_dim if hypotheses == 1 else hypotheses * (plan_dim + 1)


class Policy(nn.Module):
    """Preprocessing + PolicyNet + output decoding. `forward` is what the inference nodes call.

    forward(depth_m (B,H,W) metres float32 (+inf = no return), p_world_body (B,3), v_world (B,3),
            q_world_body (B,4) xyzw, goal_world (B,3)) -> control points in the world frame (B, K, 3);
    with several hypotheses, those of the most confident one.
    """

    def __init__(self, cfg: ModelConfig, num_ctrl_pts: int, horizon_s: float) -> None:
        super().__init__()
        self.depth_pre = DepthPreprocessor(cfg.input_height, cfg.input_width, cfg.max_depth_m)
        self.state_enc = StateEncoder(
            cfg.state_frame == "local", cfg.position_scale_m, cfg.velocity_scale_mps, cfg.velocity_input
        )
        self.codec = OutputCodec(
            num_ctrl_pts, cfg.output_frame == "local", cfg.output == "polynomial", cfg.poly_degree
        )
        prior = None
        if cfg.output_prior == "constant_velocity":
            prior = constant_velocity_prior(
                num_ctrl_pts,
                horizon_s,
                cfg.state_frame == "local",
                cfg.output == "polynomial",
                cfg.poly_degree,
                cfg.position_scale_m,
                cfg.velocity_scale_mps,
            )
        self.net = PolicyNet(
            cfg.variant,
            self.codec.out_dim,
            cfg.backbone_out,
            cfg.backbone_dropout,
            cfg.depth_mlp,
            cfg.state_mlp,
            cfg.planning_mlp,
            prior=prior,
            depth_grid=cfg.depth_grid,
            hypotheses=cfg.hypotheses,
        )
        # Top-level copies of the interface parameters: preserved as attributes of the frozen TorchScript
        # file.
        self.input_height = int(cfg.input_height)
        self.input_width = int(cfg.input_width)
        self.max_depth_m = float(cfg.max_depth_m)
        self.num_ctrl_pts = int(num_ctrl_pts)
        self.horizon_s = float(horizon_s)
        self.num_hypotheses = int(cfg.hypotheses)
        self.plan_dim = int(self.codec.out_dim)
        # model.hypotheses_first = mean: plan 0 is the regression and always flown first (its logit unused).
        self.mean_first = cfg.hypotheses_first == "mean"

    def forward(
        self, depth_m: Tensor, p_world_body: Tensor, v_world: Tensor, q_world_body: Tensor, goal_world: Tensor
    ) -> Tensor:
        _check_state_shapes(depth_m, p_world_body, v_world, q_world_body, goal_world)
        y = self.forward_prepared(self.depth_pre(depth_m), p_world_body, v_world, q_world_body, goal_world)
        return self.codec.decode(self.select(y), p_world_body, q_world_body)

    @torch.jit.export
    def split_hypotheses(self, y: Tensor) -> tuple[Tensor, Tensor]:
        """Flat network output (B, head width) -> plans (B, M, D) and confidence logits (B, M) (zeros for
        M = 1)."""
        m = self.num_hypotheses
        d = self.plan_dim
        if y.dim() != 2 or y.size(1) != head_output_dim(d, m):
            raise RuntimeError("network output must be (B, head width) for this policy's hypotheses")
        if m == 1:
            return y.unsqueeze(1), torch.zeros(y.size(0), 1, dtype=y.dtype, device=y.device)
        return y[:, : m * d].reshape(y.size(0), m, d), y[:, m * d :]

    @torch.jit.export
    def select(self, y: Tensor) -> Tensor:
        """Flat network output -> the plan flown first (B, D): the largest logit's (the first on ties), or
        plan 0 with model.hypotheses_first = mean."""
        if self.num_hypotheses == 1:
            return y
        plans, logits = self.split_hypotheses(y)
        if self.mean_first:
            return plans[:, 0]
        best = torch.argmax(logits, dim=1)
        return plans[torch.arange(plans.size(0), device=y.device), best]

    @torch.jit.export
    def preprocess_depth(self, depth_m: Tensor) -> Tensor:
        return self.depth_pre(depth_m)

    @torch.jit.export
    def forward_prepared(
        self, depth_x: Tensor, p_world_body: Tensor, v_world: Tensor, q_world_body: Tensor, goal_world: Tensor
    ) -> Tensor:
        """Preprocessed depth (B,1,h,w) + raw state -> flat output vector in the training representation."""
        return self.net(depth_x, self.state_enc(p_world_body, v_world, q_world_body, goal_world))

    @torch.jit.export
    def encode_target(self, ctrl_world: Tensor, p_world_body: Tensor, q_world_body: Tensor) -> Tensor:
        return self.codec.encode(ctrl_world, p_world_body, q_world_body)

    @torch.jit.export
    def decode(self, y: Tensor, p_world_body: Tensor, q_world_body: Tensor) -> Tensor:
        return self.codec.decode(y, p_world_body, q_world_body)


def _check_state_shapes(depth_m: Tensor, p: Tensor, v: Tensor, q: Tensor, goal: Tensor) -> None:
    b = depth_m.size(0)
    if p.dim() != 2 or p.size(0) != b or p.size(1) != 3:
        raise RuntimeError("p_world_body must be (B, 3) with B = depth batch size")
    if v.dim() != 2 or v.size(0) != b or v.size(1) != 3:
        raise RuntimeError("v_world must be (B, 3) with B = depth batch size")
    if q.dim() != 2 or q.size(0) != b or q.size(1) != 4:
        raise RuntimeError("q_world_body must be (B, 4) xyzw with B = depth batch size")
    if goal.dim() != 2 or goal.size(0) != b or goal.size(1) != 3:
        raise RuntimeError("goal_world must be (B, 3) with B = depth batch size")


def build_policy(cfg: ModelConfig, num_ctrl_pts: int, horizon_s: float) -> Policy:
    """A Policy, randomly initialised (global torch RNG: seed it first) or with torchvision's backbone."""
    policy = Policy(cfg, num_ctrl_pts, horizon_s)
    if cfg.backbone_weights:
        # weights_only=True: a state dict of tensors, nothing else is built.
        state = read_checkpoint_file(cfg.backbone_weights, "model.backbone_weights: file")
        if not isinstance(state, dict):
            raise ValueError(f"model.backbone_weights: {cfg.backbone_weights} does not hold a state dict")
        policy.net.backbone.load_torchvision_state_dict(state, load_classifier=cfg.backbone_out == 1000)
    return policy
