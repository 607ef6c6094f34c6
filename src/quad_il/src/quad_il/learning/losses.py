"""Training losses of the thesis, equations (3.1) and (3.2), on the flattened output vector.

Per sample, with a_e the expert's flattened B-spline (or coefficient matrix), a_l the learned one, n elements:
    MSE(a_e, a_l) = sum_i (a_e_i - a_l_i)^2 / n        (3.1)
    SSE(a_e, a_l) = sum_i (a_e_i - a_l_i)^2            (3.2)
A batch's loss is the mean of its per-sample losses, so it does not grow with the batch size; SSE = n * MSE.
"""

from __future__ import annotations

from typing import Literal

import torch
from torch import Tensor

from quad_il.learning.eil import eil_row_terms

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
    """EIL's objective per row (quad_il.learning.eil, docs/imitation_learning.md "EIL") on flat B-spline
    vectors (B, 3K) in one frame: GOOD rows max(0, D - B), BAD rows max(0, B - D), DEMO/INTERVENTION rows
    lambda D, with D the mean squared control-point distance between the row's label and the prediction.
    Their mean equals `eil_loss(...).total` (both use `eil_row_terms`)."""
    if pred.shape != target.shape or pred.dim() != 2 or pred.size(1) % 3 != 0:
        raise ValueError(
            f"EIL needs (B, 3K) predictions and labels, got {tuple(pred.shape)}, {tuple(target.shape)}"
        )
    good, bad, intervention = eil_row_terms(pred, target, partition, threshold_b_m)
    return good + bad + intervention_weight * intervention


def wta_per_sample(
    name: LossName,
    plans: Tensor,
    logits: Tensor,
    target: Tensor,
    relax: float,
    confidence_weight: float,
) -> tuple[Tensor, Tensor]:
    """Relaxed winner-takes-all over M hypotheses (Rupprecht et al., "Learning in an Uncertain World:
    Representing Ambiguity Through Multiple Hypotheses", ICCV 2017) with a confidence classifier.

    plans (B, M, D), logits (B, M), target (B, D). Per sample, with e_m the loss `name` (eq. 3.1 or 3.2) of
    hypothesis m and w = argmin_m e_m the winner:
        (1 - relax) e_w + relax / (M - 1) sum_{m != w} e_m + confidence_weight * CE(logits, w)
    The winner takes the regression (so the hypotheses spread over the modes of the expert's choices instead
    of averaging them); `relax` keeps the others from never learning; the cross-entropy teaches the logits
    which hypothesis the expert's plan is nearest to. Returns (per-sample loss (B,), winner index (B,)).
    """
    if plans.dim() != 3 or logits.shape != plans.shape[:2] or target.shape != (plans.size(0), plans.size(2)):
        raise ValueError(
            f"expected plans (B, M, D), logits (B, M), target (B, D); got {tuple(plans.shape)}, "
            f"{tuple(logits.shape)}, {tuple(target.shape)}"
        )
    m = plans.size(1)
    if m < 2:
        raise ValueError(f"winner-takes-all needs at least 2 hypotheses, got {m}")
    if not 0.0 <= relax < 1.0:
        raise ValueError(f"relax must be in [0, 1), got {relax}")
    b, _, d = plans.shape
    per_hyp = per_sample_loss(name, plans.reshape(b * m, d), target.repeat_interleave(m, dim=0)).reshape(b, m)
    winner = torch.argmin(per_hyp.detach(), dim=1)
    one_hot = torch.nn.functional.one_hot(winner, m).to(per_hyp.dtype)
    weights = (1.0 - relax) * one_hot + relax / (m - 1) * (1.0 - one_hot)
    regression = (weights * per_hyp).sum(dim=1)
    confidence = torch.nn.functional.cross_entropy(logits, winner, reduction="none")
    return regression + confidence_weight * confidence, winner
