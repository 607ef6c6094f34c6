"""TorchScript export of a trained policy, with its preprocessing, for the inference nodes (issue 8).

The file is `torch.jit.freeze(torch.jit.script(inference_module(policy)))` saved with one extra file,
`quad_il_policy.json` (read in C++ with `torch::jit::load(path, device, extra_files)`, in Python with
`torch.jit.load(path, _extra_files=...)`). Its methods:

    forward(depth_m (B,H,W) float32 metres, p_world_body (B,3), v_world (B,3), q_world_body (B,4) xyzw,
            goal_world (B,3)) -> control points (B, K, 3) in the world frame, float32
    preprocess_depth(depth_m) -> (B,1,h,w)  (exactly the training preprocessing)
    forward_prepared(depth_x, p, v, q, goal) -> flat output in the training representation
    encode_target(ctrl_world, p, q), decode(y, p, q)   (y: one plan, D values)
    select(y) -> the flown plan (D values); split_hypotheses(y) -> plans (B, M, D), logits (B, M)

and attributes input_height, input_width, max_depth_m, num_ctrl_pts, horizon_s, num_hypotheses, plan_dim.
With model.hypotheses = M > 1 the flat output holds M plans and M confidence logits (model.py); the metadata's
`output.hypotheses` says M (files without the key have one plan). Any depth image size is
accepted (the file resizes); the control points span `horizon_s` seconds from the depth frame's stamp.

`inference_module` is an eval-mode copy of the policy, made faster for CPU inference without changing what
it computes: the backbone's last Linear (1024 -> 1000 for MobileNetV3-Small) and the depth MLP's first Linear
(1000 -> 128) are merged into one (`fold_backbone_head`: two affine maps with nothing between them), and the
convolution weights are stored channels_last (oneDNN then runs the depthwise convolutions without reorders).
The caller's policy, and so the training checkpoint, keep the 1000-wide layer; the export check compares the
reloaded file with the eager, unfolded policy.
"""

from __future__ import annotations

import contextlib
import copy
import json
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch
from torch import nn

from quad_il.learning.config import ModelConfig
from quad_il.learning.mobilenet_v3 import MobileNetV3
from quad_il.learning.model import Policy, PolicyNet

META_FILE = "quad_il_policy.json"
META_FORMAT = "quad_il_policy/1"
PRESERVED = [
    "preprocess_depth",
    "forward_prepared",
    "encode_target",
    "decode",
    "select",
    "split_hypotheses",
    "num_hypotheses",
    "plan_dim",
    "mean_first",
    "input_height",
    "input_width",
    "max_depth_m",
    "num_ctrl_pts",
    "horizon_s",
]


@contextlib.contextmanager
def _quiet_jit() -> Iterator[None]:
    """torch 2.13 marks TorchScript deprecated; it is still LibTorch's (C++) loading path: used on purpose."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", category=DeprecationWarning, message=r".*torch\.jit\.")
        yield


def policy_metadata(
    policy: Policy, model_cfg: dict[str, Any], extra: dict[str, Any] | None = None
) -> dict[str, Any]:
    pre = policy.depth_pre
    enc = policy.state_enc
    codec = policy.codec
    meta: dict[str, Any] = {
        "format": META_FORMAT,
        "inputs": {
            "depth_m": "(B, H, W) float32 metres, any H and W; +inf or NaN = no return",
            "p_world_body": "(B, 3) float32 m, ENU world",
            "v_world": "(B, 3) float32 m/s, world frame",
            "q_world_body": "(B, 4) float32 quaternion x, y, z, w (body -> world)",
            "goal_world": "(B, 3) float32 m, world frame",
        },
        "output": {
            "ctrl_world": "(B, K, 3) float32 m, world frame B-spline control points",
            "num_ctrl_pts": policy.num_ctrl_pts,
            "horizon_s": policy.horizon_s,
            "bspline": (
                "uniform cubic (order 3), knots (i - 3) * horizon_s / (K - 3) for i = 0..K+3, domain "
                "[0, horizon_s] seconds from the depth frame's stamp (docs/data_format.md)"
            ),
            "bspline_order": 3,
            "knot_dt_s": policy.horizon_s / (policy.num_ctrl_pts - 3) if policy.num_ctrl_pts > 3 else None,
            "network_frame": "local" if codec.local_frame else "world",
            "network_representation": "polynomial" if codec.polynomial else "bspline",
            "network_prior": str(model_cfg.get("output_prior", "none")),
            "hypotheses": policy.num_hypotheses,
            "hypotheses_first": "mean" if policy.mean_first else "confidence",
            "hypotheses_layout": (
                "one plan of D values"
                if policy.num_hypotheses == 1
                else (
                    "M plans of D values each, then M confidence logits; plan 0 is flown first, then the "
                    "others by logit"
                    if policy.mean_first
                    else "M plans of D values each, then M confidence logits; the largest logit is flown"
                )
            ),
        },
        "preprocessing": {
            "depth": (
                "float32; NaN,+inf -> max_depth_m, -inf -> 0; clamp [0, max_depth_m]; "
                "adaptive_avg_pool2d to (input_height, input_width); divide by max_depth_m; round to float16"
            ),
            "input_height": pre.out_height,
            "input_width": pre.out_width,
            "max_depth_m": pre.max_depth_m,
            "state_frame": "local" if enc.local_frame else "world",
            "position_scale_m": enc.position_scale_m,
            "velocity_scale_mps": enc.velocity_scale_mps,
            "velocity_input": enc.velocity_gain != 0.0,
        },
        "model": model_cfg,
    }
    if extra:
        meta.update(extra)
    return meta


def fold_backbone_head(policy: Policy) -> Policy:
    """An eval-mode deep copy of `policy` in which the backbone's last Linear is folded into the depth MLP.

    In `PolicyNet.forward` the backbone's logits `z = W1 h + b1` (`net.backbone.classifier[-1]`, after the
    classifier's Hardswish and Dropout) go straight into `net.depth_mlp[0]`: `W2 z + b2`, then ReLU. The two
    affine maps compose into one, `(W2 W1) h + (W2 b1 + b2)`, computed in float64 and stored in the weights'
    dtype: the copy's `depth_mlp[0]` becomes that Linear (1024 -> 128 for MobileNetV3-Small) and the
    classifier's last layer an `nn.Identity`, so the backbone of the copy returns its hidden features. The
    same function up to float rounding, with one large matrix product fewer. `policy` is not modified.

    Raises ValueError when the network does not have the structure the fold relies on.
    """
    net = getattr(policy, "net", None)
    if not isinstance(net, PolicyNet) or type(net).forward is not PolicyNet.forward:
        raise ValueError(
            "fold_backbone_head: policy.net must be a PolicyNet with its own forward, "
            f"got {type(net).__name__}"
        )
    backbone = net.backbone
    if not isinstance(backbone, MobileNetV3) or type(backbone).forward is not MobileNetV3.forward:
        raise ValueError(
            "fold_backbone_head: policy.net.backbone must be a MobileNetV3 with its own forward, "
            f"got {type(backbone).__name__}"
        )
    classifier, depth_mlp = backbone.classifier, net.depth_mlp
    last = classifier[-1] if isinstance(classifier, nn.Sequential) and len(classifier) > 0 else None
    first = depth_mlp[0] if isinstance(depth_mlp, nn.Sequential) and len(depth_mlp) > 0 else None
    if not isinstance(last, nn.Linear):
        raise ValueError(
            "fold_backbone_head: the backbone classifier's last layer must be nn.Linear, "
            f"got {type(last).__name__}"
        )
    if not isinstance(first, nn.Linear):
        raise ValueError(f"fold_backbone_head: depth_mlp[0] must be nn.Linear, got {type(first).__name__}")
    if first.in_features != last.out_features:
        raise ValueError(
            f"fold_backbone_head: depth_mlp[0] takes {first.in_features} features but the backbone "
            f"classifier gives {last.out_features}"
        )
    with torch.no_grad():
        w1, w2 = last.weight.double(), first.weight.double()
        b1 = last.bias.double() if last.bias is not None else torch.zeros_like(w1[:, 0])
        b2 = first.bias.double() if first.bias is not None else torch.zeros_like(w2[:, 0])
        weight = w2 @ w1
        bias = w2 @ b1 + b2
        folded = nn.Linear(
            last.in_features, first.out_features, device=first.weight.device, dtype=first.weight.dtype
        )
        folded.weight.copy_(weight)
        folded.bias.copy_(bias)
    out = copy.deepcopy(policy).eval()
    out.net.backbone.classifier[-1] = nn.Identity()
    out.net.depth_mlp[0] = folded.eval()
    return out


def inference_module(policy: Policy) -> Policy:
    """What `export_torchscript` scripts: `fold_backbone_head(policy)` with channels_last conv weights."""
    return fold_backbone_head(policy).to(memory_format=torch.channels_last)


def export_torchscript(
    policy: Policy,
    path: str | Path,
    meta: dict[str, Any],
    check_inputs: tuple[torch.Tensor, ...] | None = None,
    tol: float = 1e-4,
) -> float:
    """Script, freeze and save `inference_module(policy)`, a folded, channels_last copy (`policy` itself is
    only put in eval mode during the call); with `check_inputs` the reloaded file is run against the eager,
    unfolded policy.

    Returns the largest absolute difference found (0.0 without check inputs); raises RuntimeError above `tol`.
    """
    was_training = policy.training
    policy.eval()
    try:
        with _quiet_jit():
            frozen = torch.jit.freeze(torch.jit.script(inference_module(policy)), preserved_attrs=PRESERVED)
            out = Path(path)
            tmp = out.with_name(out.name + ".partial")
            torch.jit.save(
                frozen, str(tmp), _extra_files={META_FILE: json.dumps(meta, indent=1, sort_keys=True)}
            )
        tmp.replace(out)
        diff = 0.0
        if check_inputs is not None:
            with _quiet_jit():
                loaded = torch.jit.load(str(out))
            with torch.no_grad():
                diff = float((loaded(*check_inputs) - policy(*check_inputs)).abs().max())
            if not diff <= tol:
                raise RuntimeError(
                    f"TorchScript export differs from the eager policy by {diff:.3g} (> {tol})"
                )
        return diff
    finally:
        policy.train(was_training)


def seeded_check_inputs(
    model_cfg: ModelConfig, seed: int, goal_offset_m: float = 0.0
) -> tuple[torch.Tensor, ...]:
    """Seeded raw inputs (batch of 2, depth at twice the input size) for the export's eager-vs-file check."""
    g = torch.Generator().manual_seed(seed)
    b = 2
    return (
        torch.rand(b, 2 * model_cfg.input_height, 2 * model_cfg.input_width, generator=g) * 12.0,
        torch.rand(b, 3, generator=g) * 10.0,
        torch.rand(b, 3, generator=g),
        torch.nn.functional.normalize(torch.rand(b, 4, generator=g) + 0.1, dim=1),
        torch.rand(b, 3, generator=g) * 20.0 + goal_offset_m,
    )


def export_policy_file(
    policy: Policy, model_cfg: ModelConfig, path: str | Path, run: dict, check: tuple[torch.Tensor, ...]
) -> Path:
    """Export as training does, with `run` as the metadata's run section (creates the parent directory)."""
    meta = policy_metadata(policy, model_cfg.model_dump(mode="json"), {"run": run})
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    export_torchscript(policy, out, meta, check)
    return out


def load_exported(path: str | Path) -> tuple[torch.jit.ScriptModule, dict[str, Any]]:
    """(module, metadata) of an exported policy file."""
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"policy file not found: {p}")
    extra = {META_FILE: ""}
    with _quiet_jit():
        module = torch.jit.load(str(p), map_location="cpu", _extra_files=extra)
    raw = extra[META_FILE]
    if not raw:
        raise ValueError(f"{p}: not a quad_il policy export (no {META_FILE})")
    meta = json.loads(raw)
    if meta.get("format") != META_FORMAT:
        raise ValueError(f"{p}: unsupported policy format {meta.get('format')!r} (want {META_FORMAT})")
    return module, meta
