"""Training losses of the thesis, equations (3.1) and (3.2), on the flattened output vector.

Per sample, with a_e the expert's flattened B-spline (or coefficient matrix), a_l the learned one, n elements:
    MSE(a_e, a_l) = sum_i (a_e_i - a_l_i)^2 / n        (3.1)
    SSE(a_e, a_l) = sum_i (a_e_i - a_l_i)^2            (3.2)
A batch's loss is the mean of its per-sample losses, so it does not grow with the batch size; SSE = n * MSE.
"""

from __future__ import annotations

from typing import Literal

from torch import Tensor

LossName = Literal["mse", "sse", "eil"]


def _squared_error(pred: Tensor, target: Tensor) -> Tensor:
    if pred.shape != target.shape:
        raise ValueError(f"prediction shape {tuple(pred.shape)} != target shape {tuple(target.shape)}")
    if pred.dim() < 2:
        raise ValueError(f"expected (batch, ...) tensors, got shape {tuple(pred.shape)}")
    return (pred - target).pow(2).flatten(1)


def mse_per_sample(pred: Tensor, target: Tensor) -> Tensor:
    """Equation (3.1) for each sample: (B,) tensor."""
    return _squared_error(pred, target).mean(dim=1)


def sse_per_sample(pred: Tensor, target: Tensor) -> Tensor:
    """Equation (3.2) for each sample: (B,) tensor."""
    return _squared_error(pred, target).sum(dim=1)


def per_sample_loss(name: LossName, pred: Tensor, target: Tensor) -> Tensor:
    if name == "mse":
        return mse_per_sample(pred, target)
    if name == "sse":
        return sse_per_sample(pred, target)
    raise ValueError(f"loss must be 'mse' or 'sse', got {name!r}")


def batch_loss(name: LossName, pred: Tensor, target: Tensor) -> tuple[Tensor, Tensor]:
    """(mean over the batch, per-sample losses)."""
    per = per_sample_loss(name, pred, target)
    return per.mean(), per


def eil_per_sample(
    pred: Tensor, target: Tensor, partition: Tensor, threshold_b_m: float, intervention_weight: float
) -> Tensor:
    """EIL's objective per row (quad_il.imitation.losses, docs/imitation_learning.md "EIL") on flat B-spline
    vectors (B, 3K) in one frame: GOOD rows max(0, D - B), BAD rows max(0, B - D), DEMO/INTERVENTION rows
    lambda D, with D the mean squared control-point distance between the row's label and the prediction.
    Their mean equals `eil_loss(...).total` (both use `eil_row_terms`)."""
    from quad_il.imitation.losses import eil_row_terms

    if pred.shape != target.shape or pred.dim() != 2 or pred.size(1) % 3 != 0:
        raise ValueError(
            f"EIL needs (B, 3K) predictions and labels, got {tuple(pred.shape)}, {tuple(target.shape)}"
        )
    good, bad, intervention = eil_row_terms(pred, target, partition, threshold_b_m)
    return good + bad + intervention_weight * intervention
