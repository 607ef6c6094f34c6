"""The interface parameters of an exported policy, read from its `quad_il_policy.json` (learning/export.py).

The same keys and checks as the C++ `quad_policy::ParsePolicyMeta`: errors name the file and the key.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

META_FORMAT = "quad_il_policy/1"
BSPLINE_ORDER = 3
MAX_HYPOTHESES = 8  # model.hypotheses' bound (learning/config.py)


class PolicyFormatError(ValueError):
    """An exported policy file is unusable; the message names the file and the key."""


Frame = Literal["world", "local"]


@dataclass(frozen=True)
class PolicyMeta:
    input_height: int
    input_width: int
    max_depth_m: float
    state_frame: Frame
    position_scale_m: float
    velocity_scale_mps: float
    num_ctrl_pts: int
    horizon_s: float
    output_frame: Frame
    representation: Literal["bspline", "polynomial"]
    poly_degree: int  # 0 for the B-spline representation
    velocity_input: bool = True  # false: the state's velocity entries are zero (model.velocity_input)
    hypotheses: int = 1  # plans per forward pass (model.hypotheses); files without output.hypotheses: 1
    # True: plan 0 (the regression) is flown first, the others follow by logit (output.hypotheses_first
    # "mean"); false: all by logit ("confidence", and files without the key).
    mean_first: bool = False

    @property
    def knot_dt_s(self) -> float:
        return self.horizon_s / (self.num_ctrl_pts - BSPLINE_ORDER)

    @property
    def output_dim(self) -> int:
        """Values of one plan (what `decode` takes)."""
        return 3 * (self.poly_degree + 1 if self.representation == "polynomial" else self.num_ctrl_pts)

    @property
    def network_output_dim(self) -> int:
        """Values the network returns: one plan, or M plans and M confidence logits."""
        return self.output_dim if self.hypotheses == 1 else self.hypotheses * (self.output_dim + 1)


def _get(meta: dict[str, Any], path: str, source: str) -> Any:
    node: Any = meta
    for part in path.split("."):
        if not isinstance(node, dict) or part not in node:
            raise PolicyFormatError(f"{source}: policy metadata key '{path}' is missing")
        node = node[part]
    return node


def _optional_bool(meta: dict[str, Any], path: str, default: bool, source: str) -> bool:
    """A boolean key that files exported before it existed lack (then `default`)."""
    parent, _, key = path.rpartition(".")
    node = _get(meta, parent, source) if parent else meta
    if not isinstance(node, dict) or key not in node:
        return default
    value = node[key]
    if not isinstance(value, bool):
        raise PolicyFormatError(
            f"{source}: policy metadata key '{path}' must be true or false, got {value!r}"
        )
    return value


def _int_at_least(meta: dict[str, Any], path: str, lo: int, source: str) -> int:
    v = _get(meta, path, source)
    if isinstance(v, bool) or not isinstance(v, int):
        raise PolicyFormatError(f"{source}: policy metadata key '{path}' has an unexpected value {v!r}")
    if v < lo:
        raise PolicyFormatError(f"{source}: policy metadata key '{path}' must be >= {lo}, got {v}")
    return v


def _optional_int_in(meta: dict[str, Any], path: str, lo: int, hi: int, default: int, source: str) -> int:
    """An integer key in [lo, hi] that files exported before it existed lack (then `default`)."""
    parent, _, key = path.rpartition(".")
    node = _get(meta, parent, source) if parent else meta
    if not isinstance(node, dict) or key not in node:
        return default
    v = node[key]
    if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
        raise PolicyFormatError(
            f"{source}: policy metadata key '{path}' must be an integer in [{lo}, {hi}], got {v!r}"
        )
    return v


def _positive(meta: dict[str, Any], path: str, source: str) -> float:
    v = _get(meta, path, source)
    if isinstance(v, bool) or not isinstance(v, int | float) or not (math.isfinite(v) and v > 0):
        raise PolicyFormatError(
            f"{source}: policy metadata key '{path}' must be a finite number > 0, got {v!r}"
        )
    return float(v)


def _frame(meta: dict[str, Any], path: str, source: str) -> Frame:
    v = _get(meta, path, source)
    if v not in ("world", "local"):
        raise PolicyFormatError(
            f"{source}: policy metadata key '{path}' must be 'world' or 'local', got {v!r}"
        )
    return v


def parse_policy_meta(meta: dict[str, Any], source: str) -> PolicyMeta:
    fmt = _get(meta, "format", source)
    if fmt != META_FORMAT:
        raise PolicyFormatError(
            f"{source}: unsupported policy format {fmt!r} (this build reads {META_FORMAT!r})"
        )
    order = _get(meta, "output.bspline_order", source)
    if order != BSPLINE_ORDER:
        raise PolicyFormatError(
            f"{source}: policy metadata key 'output.bspline_order' must be {BSPLINE_ORDER}, got {order!r}"
        )
    rep = _get(meta, "output.network_representation", source)
    if rep not in ("bspline", "polynomial"):
        raise PolicyFormatError(
            f"{source}: policy metadata key 'output.network_representation' must be 'bspline' or "
            f"'polynomial', got {rep!r}"
        )
    return PolicyMeta(
        input_height=_int_at_least(meta, "preprocessing.input_height", 8, source),
        input_width=_int_at_least(meta, "preprocessing.input_width", 8, source),
        max_depth_m=_positive(meta, "preprocessing.max_depth_m", source),
        state_frame=_frame(meta, "preprocessing.state_frame", source),
        position_scale_m=_positive(meta, "preprocessing.position_scale_m", source),
        velocity_scale_mps=_positive(meta, "preprocessing.velocity_scale_mps", source),
        num_ctrl_pts=_int_at_least(meta, "output.num_ctrl_pts", BSPLINE_ORDER + 1, source),
        horizon_s=_positive(meta, "output.horizon_s", source),
        output_frame=_frame(meta, "output.network_frame", source),
        representation=rep,
        poly_degree=_int_at_least(meta, "model.poly_degree", 1, source) if rep == "polynomial" else 0,
        velocity_input=_optional_bool(meta, "preprocessing.velocity_input", True, source),
        hypotheses=_optional_int_in(meta, "output.hypotheses", 1, MAX_HYPOTHESES, 1, source),
        mean_first=_hypotheses_first(meta, source) == "mean",
    )


def _hypotheses_first(meta: dict[str, Any], source: str) -> str:
    """output.hypotheses_first: "confidence" (and files without the key) or "mean"."""
    out = _get(meta, "output", source)
    v = out.get("hypotheses_first", "confidence") if isinstance(out, dict) else "confidence"
    if v not in ("confidence", "mean"):
        raise PolicyFormatError(
            f"{source}: policy metadata key 'output.hypotheses_first' must be 'confidence' or 'mean', "
            f"got {v!r}"
        )
    return v
