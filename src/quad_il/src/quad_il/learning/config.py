"""Typed training configuration (pydantic v2, unknown keys rejected) loaded from YAML with `--set` overrides.

`load_config([base.yaml, experiment.yaml], ["optim.lr=1e-3", ...])` deep-merges the files left to right,
applies the overrides (values parsed as YAML scalars/lists) and validates; any problem is a `ConfigError`
whose message names the key and the value. Every key is documented in docs/learning.md and config/train.yaml.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from quad_il.tools.config_overlay import deep_merge


class ConfigError(ValueError):
    """A configuration file or override is invalid; the message names the key and the value."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class RunConfig(_Strict):
    name: str = Field("default", min_length=1, pattern=r"^[A-Za-z0-9_.\-]+$")
    out_dir: str = "runs"
    seed: int = Field(0, ge=0, le=2**31 - 1)
    num_threads: int = Field(2, ge=1, le=256)
    deterministic: bool = True
    init_weights: str | None = None  # a training checkpoint (.pt) whose network weights start this run


class ShardConfig(_Strict):
    """Reading shard directories directly: the fixed B-spline representation (as the npz postprocessing)."""

    num_ctrl_pts: int = Field(10, ge=4, le=1000)
    horizon_s: float = Field(1.5, gt=0.0, le=1000.0)  # thesis 2.0; 1.5 measured (docs/RESULTS.md, issue 33)
    on_corrupt: Literal["raise", "skip"] = "raise"


class DataConfig(_Strict):
    paths: list[str] = Field(default_factory=list)
    val_fraction: float = Field(0.1, gt=0.0, lt=1.0)
    train_episode_fraction: float = Field(1.0, gt=0.0, le=1.0)
    # permuted: a seeded permutation of all episodes (moves episodes between the sides when data is added);
    # hashed: each episode's side from its own hash (stable across DAgger rounds). dataset.split_by_episode.
    split: Literal["permuted", "hashed"] = "permuted"
    num_workers: int = Field(1, ge=0, le=16)
    # Share of training samples seen in a mirror each epoch (preprocessing.mirror_about_heading: the depth
    # image flipped left to right, state, goal and plan reflected about the heading plane); 0 = off. Which
    # samples is a function of (run.seed, epoch, sample), the same with any number of processes.
    mirror_probability: float = Field(0.0, ge=0.0, le=1.0)
    hash_files: bool = True
    shards: ShardConfig = ShardConfig()


class ModelConfig(_Strict):
    variant: Literal["small", "large"] = "small"
    input_height: int = Field(96, ge=32, le=1024)
    input_width: int = Field(96, ge=32, le=1024)
    max_depth_m: float = Field(10.0, gt=0.0)
    backbone_out: int = Field(1000, ge=1)
    backbone_dropout: float = Field(0.2, ge=0.0, lt=1.0)
    backbone_weights: str | None = None
    depth_mlp: list[int] = Field(default_factory=lambda: [128, 64, 32], min_length=1)
    state_mlp: list[int] = Field(default_factory=lambda: [64, 32, 32], min_length=1)
    planning_mlp: list[int] = Field(default_factory=lambda: [64, 128, 128], min_length=1)
    state_frame: Literal["world", "local"] = "world"
    output_frame: Literal["world", "local"] = "world"
    output: Literal["bspline", "polynomial"] = "bspline"
    output_prior: Literal["none", "constant_velocity"] = "none"
    poly_degree: int = Field(5, ge=1)
    position_scale_m: float = Field(10.0, gt=0.0)
    velocity_scale_mps: float = Field(3.0, gt=0.0)
    velocity_input: bool = True  # false: the state's velocity entries are zero (no copying of the motion)
    # [rows, cols]: also give the planning MLP the nearest surface of each cell of a coarse grid over the
    # preprocessed depth (max-pooled nearness 1 - depth / max_depth_m), beside the backbone's features.
    # [] = off (the thesis's network). docs/learning.md, "Depth grid".
    depth_grid: list[int] = Field(default_factory=list)
    # Plans per decision (multiple-hypothesis output, docs/learning.md "Multiple hypotheses"): M > 1 makes the
    # head output M plans and M confidence logits, trained winner-takes-all; 1 = the thesis's single plan.
    hypotheses: int = Field(1, ge=1, le=8)
    # Which plan is flown first: `confidence`, the largest logit's (all M trained winner-takes-all); `mean`,
    # plan 0, trained on every sample with optim.loss as the single plan is, while plans 1..M-1 are trained
    # winner-takes-all as alternatives (ordered by their logits); needs hypotheses >= 3.
    hypotheses_first: Literal["confidence", "mean"] = "confidence"

    @model_validator(mode="after")
    def _widths_positive(self) -> ModelConfig:
        for key in ("depth_mlp", "state_mlp", "planning_mlp"):
            widths = getattr(self, key)
            if any(w < 1 for w in widths):
                raise ValueError(f"model.{key}: every width must be >= 1, got {widths}")
        if self.depth_grid and (
            len(self.depth_grid) != 2
            or not 1 <= self.depth_grid[0] <= self.input_height
            or not 1 <= self.depth_grid[1] <= self.input_width
        ):
            raise ValueError(
                f"model.depth_grid must be [] or [rows, cols] with 1 <= rows <= input_height "
                f"({self.input_height}) and 1 <= cols <= input_width ({self.input_width}), "
                f"got {self.depth_grid}"
            )
        if self.hypotheses_first == "mean" and self.hypotheses < 3:
            raise ValueError(
                "model.hypotheses_first: mean needs model.hypotheses >= 3 (the mean plan and at least two "
                f"alternatives trained winner-takes-all), got {self.hypotheses}"
            )
        if self.output_prior != "none" and not self.velocity_input:
            raise ValueError(
                "model.output_prior: the constant-velocity prior needs model.velocity_input: true"
            )
        if self.output_prior != "none" and self.state_frame != self.output_frame:
            raise ValueError(
                f"model.output_prior: {self.output_prior} needs state_frame == output_frame (the prior is a "
                f"linear map of the state vector), got {self.state_frame} and {self.output_frame}"
            )
        return self


class EILTrainConfig(_Strict):
    """optim.loss = eil (docs/imitation_learning.md, "EIL"): rows' partitions from the npz `il_partition`."""

    threshold_b_m: float = Field(
        0.5, gt=0.0
    )  # B = threshold_b_m ** 2 on the mean squared ctrl-point distance
    intervention_weight: float = Field(1.0, ge=0.0)  # lambda on the DEMO/INTERVENTION regression rows


class OptimConfig(_Strict):
    optimizer: Literal["adam", "adamw", "sgd"] = "adam"
    lr: float = Field(1e-3, gt=0.0)
    weight_decay: float = Field(0.0, ge=0.0)
    momentum: float = Field(0.9, ge=0.0, lt=1.0)
    batch_size: int = Field(32, ge=2)
    epochs: int = Field(30, ge=1)
    loss: Literal["mse", "sse", "eil"] = "mse"
    eil: EILTrainConfig = EILTrainConfig()
    grad_clip_norm: float | None = Field(None, gt=0.0)
    channels_last: bool = True
    # model.hypotheses > 1 (relaxed winner-takes-all, Rupprecht et al. 2017): the share of a sample's loss
    # spread evenly over the hypotheses that did not win, and the weight of the confidence logits' cross-
    # entropy against the winner's index.
    wta_relax: float = Field(0.05, ge=0.0, lt=1.0)
    wta_confidence_weight: float = Field(0.05, ge=0.0)


class CustomSchedulerConfig(_Strict):
    first_decay_steps: int = Field(50000, ge=1)
    t_mul: float = Field(1.5, ge=1.0)
    m_mul: float = Field(1.0, gt=0.0, le=1.0)
    alpha: float = Field(0.01, ge=0.0, le=1.0)


class PytorchSchedulerConfig(_Strict):
    T_0: int = Field(500, ge=1)
    T_mult: int = Field(1, ge=1)
    eta_min: float = Field(1e-5, ge=0.0)


class CosineSchedulerConfig(_Strict):
    alpha: float = Field(0.01, ge=0.0, le=1.0)  # final lr / initial lr


class SchedulerConfig(_Strict):
    # custom / pytorch: the thesis's restarts (Tables 3.3 / 3.2); cosine: one cosine decay from optim.lr to
    # cosine.alpha * optim.lr over every optimiser step of the run (optim.epochs), so the last epochs train at
    # a small rate whatever the data size; none: constant optim.lr.
    name: Literal["custom", "pytorch", "cosine", "none"] = "custom"
    custom: CustomSchedulerConfig = CustomSchedulerConfig()
    pytorch: PytorchSchedulerConfig = PytorchSchedulerConfig()
    cosine: CosineSchedulerConfig = CosineSchedulerConfig()


class LogConfig(_Strict):
    progress: bool = True
    tensorboard: bool = True
    export_torchscript: bool = True
    plots: bool = True


class DistConfig(_Strict):
    """Distributed data-parallel training (torchrun, docs/scaling.md); ignored by a single process."""

    backend: Literal["auto", "gloo", "nccl"] = "auto"  # auto: nccl when CUDA is available, else gloo
    # BatchNorm statistics over the global batch (exactly one process's training, but CrossProcessBatchNorm2d
    # roughly doubles a CPU step); false: per-process statistics, as plain DDP
    sync_batchnorm: bool = False
    timeout_s: float = Field(1800.0, gt=0.0)  # collective operations' timeout


class TrainConfig(_Strict):
    run: RunConfig = RunConfig()
    data: DataConfig = DataConfig()
    model: ModelConfig = ModelConfig()
    optim: OptimConfig = OptimConfig()
    scheduler: SchedulerConfig = SchedulerConfig()
    log: LogConfig = LogConfig()
    dist: DistConfig = DistConfig()

    @model_validator(mode="after")
    def _eil_needs_control_points(self) -> TrainConfig:
        if self.optim.loss == "eil" and self.model.output != "bspline":
            raise ValueError(
                "optim.loss: eil measures distances between control points: it needs model.output = bspline, "
                f"got {self.model.output}"
            )
        if self.optim.loss == "eil" and self.model.hypotheses > 1:
            raise ValueError(
                "optim.loss: eil scores one plan per row; it cannot train model.hypotheses = "
                f"{self.model.hypotheses} (use mse or sse)"
            )
        return self

    def to_dict(self) -> dict[str, Any]:
        return self.model_dump(mode="json")


# Keys that may differ between a run and its resumption (they do not change the training curve).
RESUME_MUTABLE_KEYS = frozenset(
    {"optim.epochs", "data.paths", "data.num_workers", "data.hash_files", "run.out_dir"}
    | {f"log.{k}" for k in LogConfig.model_fields}
    | {f"dist.{k}" for k in DistConfig.model_fields}
)


def _format_validation_error(err: ValidationError) -> str:
    lines = []
    for e in err.errors():
        key = ".".join(str(p) for p in e["loc"]) or "<root>"
        value = e.get("input")
        shown = "" if isinstance(value, dict) else f" (got {value!r})"
        lines.append(f"config key '{key}': {e['msg']}{shown}")
    return "invalid training config:\n  " + "\n  ".join(lines)


def parse_override(text: str) -> tuple[list[str], Any]:
    """'optim.lr=1e-3' -> (['optim', 'lr'], 0.001); the value is parsed as YAML."""
    if "=" not in text:
        raise ConfigError(f"override {text!r} must look like key.subkey=value")
    key, raw = text.split("=", 1)
    parts = key.strip().split(".")
    if not all(parts):
        raise ConfigError(f"override {text!r} has an empty key component")
    try:
        value = yaml.safe_load(raw) if raw.strip() else None
    except yaml.YAMLError as e:
        raise ConfigError(f"override {text!r}: value is not valid YAML: {e}") from None
    return parts, value


def apply_overrides(tree: dict[str, Any], overrides: Sequence[str]) -> dict[str, Any]:
    out = copy.deepcopy(tree)
    for text in overrides:
        parts, value = parse_override(text)
        node = out
        for i, part in enumerate(parts[:-1]):
            child = node.setdefault(part, {})
            if not isinstance(child, dict):
                raise ConfigError(f"override {text!r}: '{'.'.join(parts[: i + 1])}' is not a section")
            node = child
        node[parts[-1]] = value
    return out


def read_yaml(path: str | Path) -> dict[str, Any]:
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"config file not found: {p}")
    try:
        tree = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise ConfigError(f"config file {p} is not valid YAML: {e}") from None
    if tree is None:
        return {}
    if not isinstance(tree, dict):
        raise ConfigError(f"config file {p} must hold a mapping at the top level, got {type(tree).__name__}")
    return tree


def config_from_tree(tree: Mapping[str, Any]) -> TrainConfig:
    try:
        return TrainConfig.model_validate(tree)
    except ValidationError as e:
        raise ConfigError(_format_validation_error(e)) from None


def load_config(paths: Sequence[str | Path] = (), overrides: Sequence[str] = ()) -> TrainConfig:
    """Defaults <- each YAML file in order <- each `key=value` override; validated."""
    tree: dict[str, Any] = {}
    for p in paths:
        tree = deep_merge(tree, read_yaml(p))  # config/experiments/ overlays, in order
    return config_from_tree(apply_overrides(tree, overrides))


def flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in tree.items():
        key = f"{prefix}{k}"
        if isinstance(v, Mapping):
            out.update(flatten(v, key + "."))
        else:
            out[key] = v
    return out


def config_differences(a: TrainConfig, b: TrainConfig) -> dict[str, tuple[Any, Any]]:
    fa, fb = flatten(a.to_dict()), flatten(b.to_dict())
    return {k: (fa.get(k), fb.get(k)) for k in sorted(fa.keys() | fb.keys()) if fa.get(k) != fb.get(k)}


def dump_config(cfg: TrainConfig, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(cfg.to_dict(), sort_keys=False))
