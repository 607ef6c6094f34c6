"""A training checkpoint rebuilt from an exported (frozen) policy file, so that a shipped policy can start a
new training (a DAgger round's warm start) when its training run is gone.

An export (export.py) is `torch.jit.freeze` of a folded copy of the policy: every convolution's BatchNorm is
folded into the convolution's weight and bias, the backbone's last Linear is folded into the depth MLP's
first (`fold_backbone_head`), and the weights are graph constants. This module reads those constants back,
in the order the frozen graph uses them, into a `Policy` built from the file's model configuration:

- a convolution with a BatchNorm: the folded weight goes to the convolution; the BatchNorm is set so that
  in eval mode it adds the folded bias and nothing else. With calibration frames (`calib_depth_x`) it is set
  to mean `m` and scale `s` of each channel's convolution output on those frames (running mean `m`, running
  variance `s^2 - eps`, weight `s`, bias `b + m`), so that in training mode, where a batch's own statistics
  replace the running ones, the layer computes about what it computed in eval mode; without them, mean 0 and
  variance 1;
- convolutions and Linears without BatchNorm: weight and bias as they are;
- the folded 1024 -> 128 Linear: split into the backbone's 1024 -> 1000 Linear and the depth MLP's 1000 -> 128
  by a singular value decomposition (the product has rank <= 128); the unused 872 rows of the first keep
  their fresh initialisation and the matching columns of the second are zero.

In eval mode the rebuilt policy equals the file to float rounding; `recover_checkpoint` checks that (largest
difference over seeded inputs, refused above `tol`). What a checkpoint does not get back: the optimiser's and
the scheduler's state (a warm start does not read them) and the BatchNorm statistics of training.

    python -m quad_il.learning.unfreeze models/quad_il_policy/policy.ts \\
        --config models/quad_il_policy/train_config.yaml --calib data/dagger_r5_96 \\
        --out runs/unfrozen_r4/checkpoints/best.pt
"""

from __future__ import annotations

import argparse
import hashlib
import shlex
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from torch import nn

from quad_il.learning.checkpoint import CHECKPOINT_FORMAT, save_checkpoint
from quad_il.learning.config import ModelConfig, TrainConfig
from quad_il.learning.export import fold_backbone_head, load_exported, seeded_check_inputs
from quad_il.learning.model import Policy
from quad_il.tools.cli import HelpFormatter

WEIGHT_OPS = ("aten::conv2d", "aten::linear")


class UnfreezeError(ValueError):
    """The policy file, its configuration or the calibration data cannot give a checkpoint; says why."""


def frozen_weights(module: torch.jit.ScriptModule) -> list[tuple[str, torch.Tensor, torch.Tensor | None]]:
    """(op, weight, bias) of every convolution and Linear of the frozen forward graph, in graph order (the
    order in which forward runs them; nested blocks are visited where they stand)."""
    out: list[tuple[str, torch.Tensor, torch.Tensor | None]] = []

    def const(value: Any) -> torch.Tensor | None:
        node = value.node()
        if node.kind() != "prim::Constant":
            raise UnfreezeError("policy file: a convolution or Linear weight is not a constant (not frozen?)")
        v = node.output().toIValue()
        return v if isinstance(v, torch.Tensor) else None

    def visit(block: Any) -> None:
        for node in block.nodes():
            if node.kind() in WEIGHT_OPS:
                inputs = list(node.inputs())
                weight = const(inputs[1])
                if weight is None:
                    raise UnfreezeError(f"policy file: {node.kind()} without a weight tensor")
                out.append((node.kind(), weight.detach().clone(), _opt(const(inputs[2]))))
            for sub in node.blocks():
                visit(sub)

    visit(module.graph)
    return out


def _opt(t: torch.Tensor | None) -> torch.Tensor | None:
    return None if t is None else t.detach().clone()


def execution_order(policy: Policy, model_cfg: ModelConfig) -> list[tuple[str, nn.Module]]:
    """(name, module) of the Conv2d and Linear modules of the folded copy of `policy`, in the order its
    forward calls them (recorded with hooks on a seeded forward pass)."""
    folded = fold_backbone_head(policy).eval()
    names = {id(m): n for n, m in folded.named_modules()}
    order: list[tuple[str, nn.Module]] = []
    hooks = [
        m.register_forward_hook(lambda mod, _i, _o: order.append((names[id(mod)], mod)))
        for m in folded.modules()
        if isinstance(m, nn.Conv2d | nn.Linear)
    ]
    try:
        with torch.no_grad():
            folded(*seeded_check_inputs(model_cfg, 0))
    finally:
        for h in hooks:
            h.remove()
    return order


def _bn_of(policy: Policy, conv_name: str) -> nn.BatchNorm2d | None:
    """The BatchNorm2d that follows the convolution `conv_name` (ConvNormActivation: index 0 -> index 1)."""
    parent, _, index = conv_name.rpartition(".")
    if index != "0":
        return None
    try:
        bn = policy.get_submodule(f"{parent}.1")
    except AttributeError:
        return None
    return bn if isinstance(bn, nn.BatchNorm2d) else None


def _split_folded_linear(policy: Policy, weight: torch.Tensor, bias: torch.Tensor | None) -> None:
    """Writes the folded (backbone last Linear, depth_mlp[0]) pair back as two Linears whose product is it."""
    last: nn.Linear = policy.net.backbone.classifier[-1]
    first: nn.Linear = policy.net.depth_mlp[0]
    w = weight.double()  # (out, hidden) = (128, 1024)
    rank = min(w.shape)
    if rank > last.out_features:
        raise UnfreezeError(
            f"policy file: the folded depth Linear {tuple(w.shape)} has more than {last.out_features} "
            "independent directions: it cannot be split through the backbone's output width"
        )
    u, s, vh = torch.linalg.svd(w, full_matrices=False)  # w = u diag(s) vh, u (128, r), vh (r, 1024)
    root = s.sqrt()
    with torch.no_grad():
        # rows 0..r-1 of the backbone's Linear: sqrt(s) vh; the rest keep their initialisation
        last.weight[:rank].copy_((root[:, None] * vh).to(last.weight.dtype))
        last.bias.zero_()
        first.weight.zero_()
        first.weight[:, :rank].copy_((u * root[None, :]).to(first.weight.dtype))
        if first.bias is not None:
            first.bias.copy_(bias if bias is not None else torch.zeros_like(first.bias))


def unfreeze(
    module: torch.jit.ScriptModule,
    policy: Policy,
    model_cfg: ModelConfig,
    calib_depth_x: torch.Tensor | None = None,
) -> None:
    """Loads the frozen file's weights into `policy`, built with the file's model configuration
    `model_cfg`; with `calib_depth_x` (preprocessed frames, (N, 1, h, w)) the BatchNorms are calibrated."""
    weights = frozen_weights(module)
    order = execution_order(policy, model_cfg)
    if len(weights) != len(order):
        raise UnfreezeError(
            f"policy file: {len(weights)} convolutions and Linears in the frozen graph, the configuration's "
            f"network has {len(order)}: the file was not exported from this configuration"
        )
    folded_name = "net.depth_mlp.0"
    bns: list[tuple[nn.Conv2d, nn.BatchNorm2d, torch.Tensor]] = []
    for (op, weight, bias), (name, mod) in zip(weights, order, strict=True):
        want = "aten::conv2d" if isinstance(mod, nn.Conv2d) else "aten::linear"
        if op != want or tuple(weight.shape) != tuple(mod.weight.shape):
            raise UnfreezeError(
                f"policy file: {op} {tuple(weight.shape)} where the configuration's network has {name} "
                f"{tuple(mod.weight.shape)}: the file was not exported from this configuration"
            )
        if name == folded_name:
            _split_folded_linear(policy, weight, bias)
            continue
        target = policy.get_submodule(name)
        with torch.no_grad():
            target.weight.copy_(weight.contiguous())
            bn = _bn_of(policy, name) if isinstance(target, nn.Conv2d) else None
            if bn is not None:
                if target.bias is not None:
                    raise UnfreezeError(f"{name}: a convolution with a bias before a BatchNorm")
                bns.append((target, bn, bias if bias is not None else torch.zeros(bn.num_features)))
            elif target.bias is not None:
                target.bias.copy_(bias if bias is not None else torch.zeros_like(target.bias))
            elif bias is not None and bool((bias != 0).any()):
                raise UnfreezeError(f"{name}: the file adds a bias that the configuration's layer has not")
    for _conv, bn, b in bns:
        with torch.no_grad():
            bn.running_mean.zero_()
            bn.running_var.fill_(1.0 - bn.eps)
            bn.weight.fill_(1.0)
            bn.bias.copy_(b)
    if calib_depth_x is not None:
        _calibrate(policy, bns, calib_depth_x)


def _calibrate(
    policy: Policy, bns: list[tuple[nn.Conv2d, nn.BatchNorm2d, torch.Tensor]], depth_x: torch.Tensor
) -> None:
    """Sets each BatchNorm's statistics to its convolution's output statistics on the frames, keeping what
    the layer computes in eval mode (see the module docstring)."""
    stats: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}

    def hook(mod: nn.Module, _i: Any, out: torch.Tensor) -> None:
        x = out.double().transpose(0, 1).reshape(out.shape[1], -1)
        stats[id(mod)] = (x.mean(dim=1), x.std(dim=1))

    hooks = [conv.register_forward_hook(hook) for conv, _bn, _b in bns]
    was_training = policy.training
    policy.eval()
    try:
        with torch.no_grad():
            feats = policy.net.backbone(depth_x.float())
            del feats
    finally:
        for h in hooks:
            h.remove()
        policy.train(was_training)
    with torch.no_grad():
        for conv, bn, b in bns:
            mean, std = stats[id(conv)]
            scale = std.clamp_min(np.sqrt(2.0 * bn.eps))
            bn.running_mean.copy_(mean.to(bn.running_mean.dtype))
            bn.running_var.copy_((scale * scale - bn.eps).to(bn.running_var.dtype))
            bn.weight.copy_(scale.to(bn.weight.dtype))
            bn.bias.copy_((b.double() + mean).to(bn.bias.dtype))


def calibration_frames(dataset: Path, policy: Policy, count: int) -> torch.Tensor:
    """About `count` depth frames of a shard dataset, evenly spread over its shards and over the records of
    each (consecutive frames of one flight are alike), preprocessed as training does."""
    from quad_il.data import DatasetError
    from quad_il.data.postprocess import iter_shard_arrays

    shards = max(1, len(list(Path(dataset).glob("*.qdr"))))
    per_shard = max(1, -(-count // shards))
    frames: list[torch.Tensor] = []
    try:
        for _name, fixed in iter_shard_arrays(dataset):
            n = len(fixed.depth_m)
            pick = np.unique(np.linspace(0, n - 1, min(per_shard, n)).round().astype(np.int64))
            depth = torch.from_numpy(np.asarray(fixed.depth_m[pick], dtype=np.float32))
            frames.append(policy.depth_pre(depth))
    except (OSError, ValueError, DatasetError) as e:
        raise UnfreezeError(f"--calib {dataset}: cannot read depth frames: {e}") from None
    if not frames:
        raise UnfreezeError(f"--calib {dataset}: no depth frame to calibrate with")
    return torch.cat(frames)


def recover_checkpoint(
    policy_file: Path,
    config_file: Path,
    out: Path,
    calib: Path | None = None,
    calib_frames: int = 1024,
    tol: float = 1e-4,
    command: str = "",
) -> dict[str, Any]:
    """Writes the training checkpoint rebuilt from `policy_file` to `out` and returns a summary. The
    checkpoint records where it came from (`unfrozen_from`: the file, its sha256, the calibration data,
    `command`, and the "How it was made" part of the MODEL.md beside the file when that card names the
    file's hash), which the next model card prints as the start of its lineage."""
    try:
        module, meta = load_exported(policy_file)
    except (OSError, ValueError, RuntimeError) as e:
        raise UnfreezeError(f"{policy_file}: {e}") from None
    try:
        tree = yaml.safe_load(config_file.read_text())
        cfg = TrainConfig.model_validate(tree)
    except (OSError, ValueError) as e:
        raise UnfreezeError(f"{config_file}: not a training configuration: {e}") from None
    stored_model = meta.get("model", {})
    mine = cfg.model.model_dump(mode="json")
    differ = sorted(k for k in set(stored_model) | set(mine) if stored_model.get(k) != mine.get(k))
    if differ:
        raise UnfreezeError(
            f"{config_file}: model settings differ from those stored in {policy_file} ({', '.join(differ)})"
        )
    output = meta.get("output", {})
    num_ctrl_pts, horizon_s = int(output["num_ctrl_pts"]), float(output["horizon_s"])
    with torch.random.fork_rng():  # the unused rows' initialisation is seeded; the caller's RNG untouched
        torch.manual_seed(cfg.run.seed)
        policy = Policy(cfg.model, num_ctrl_pts, horizon_s)
    depth_x = calibration_frames(calib, policy, calib_frames) if calib is not None else None
    unfreeze(module, policy, cfg.model, depth_x)
    policy.eval()
    diff = 0.0
    for seed in range(3):
        inputs = seeded_check_inputs(cfg.model, 100 + seed)
        with torch.no_grad():
            diff = max(diff, float((module(*inputs) - policy(*inputs)).abs().max()))
    if not diff <= tol:
        raise UnfreezeError(
            f"{policy_file}: the rebuilt network differs from the file by {diff:.3g} (> {tol})"
        )
    sha = hashlib.sha256(policy_file.read_bytes()).hexdigest()
    card = policy_file.parent / "MODEL.md"
    lineage_md = ""
    if card.is_file() and sha in card.read_text():
        text = card.read_text()
        start = text.find("## How it was made")
        lineage_md = text[start:] if start >= 0 else ""
    ckpt = {
        "format": CHECKPOINT_FORMAT,
        "epoch": 0,
        "global_step": 0,
        "model": policy.state_dict(),
        "optimizer": None,
        "scheduler": None,
        "best_val_loss": float("inf"),
        "best_epoch": 0,
        "config": cfg.to_dict(),
        "num_ctrl_pts": num_ctrl_pts,
        "horizon_s": horizon_s,
        "world_size": 1,
        "unfrozen_from": {
            "policy_file": str(policy_file),
            "sha256": sha,
            "calib": str(calib or ""),
            "command": command,
            "model_card": lineage_md,
        },
    }
    out.parent.mkdir(parents=True, exist_ok=True)
    save_checkpoint(ckpt, out)
    frames = 0 if depth_x is None else len(depth_x)
    return {"out": str(out), "max_abs_diff": diff, "sha256": sha, "calib_frames": frames}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(formatter_class=HelpFormatter, description=__doc__.split("\n\n")[0])
    ap.add_argument("policy", type=Path, help="an exported policy file (policy.ts)")
    ap.add_argument(
        "--config", type=Path, required=True, help="its training configuration (train_config.yaml)"
    )
    ap.add_argument("--out", type=Path, required=True, help="the checkpoint to write (.pt)")
    ap.add_argument(
        "--calib", type=Path, help="a shard dataset whose first frames set the BatchNorm statistics"
    )
    ap.add_argument(
        "--calib-frames", type=int, default=1024, help="about how many frames --calib reads (spread evenly)"
    )
    args = ap.parse_args(argv)
    try:
        command = "python -m quad_il.learning.unfreeze " + shlex.join(sys.argv[1:] if argv is None else argv)
        summary = recover_checkpoint(
            args.policy, args.config, args.out, args.calib, args.calib_frames, command=command
        )
    except UnfreezeError as e:
        print(f"unfreeze: {e}", file=sys.stderr)
        return 2
    print(
        f"unfreeze: wrote {summary['out']} (largest difference to the file {summary['max_abs_diff']:.2e}, "
        f"{summary['calib_frames']} calibration frames)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
