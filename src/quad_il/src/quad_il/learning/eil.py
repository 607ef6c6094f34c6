"""EIL's losses (Spencer et al. 2022, "Expert Intervention Learning") on predicted vs label B-splines
(PyTorch).

EIL learns a cost Q_theta(s, a) whose minimiser is the policy, pi(s) = argmin_a Q_theta(s, a), from three
constraints with a threshold B: Q(s, a) <= B on the good-enough set G (learner in control, no intervention),
Q(s, a) > B on the bad set (the learner's actions that made the expert intervene), and Q(s, a*) < Q(s, a') for
the expert's action a* on the intervention set I. The constraints become hinge losses

    l_good = max(0, Q(s, a) - B),    l_bad = max(0, B - Q(s, a)),    l_C = sum_a' max(0, Q(s, a*) - Q(s, a')),

and the objective is sum(l_good) + sum(l_bad) + lambda * sum(l_C).

Our policy regresses a B-spline, so we take as the cost of an action its distance to the policy's prediction:

    Q_theta(s, a) = D(a, pi_theta(s)) = 1/K * sum_i || P_a,i - P_pred,i ||^2      (mean squared control-point
                                                                                  distance, m^2)

whose minimiser is pi_theta(s) itself, as EIL requires. Then
    good:          max(0, D(a_learner, pred) - B)   keep the prediction within B of the accepted plan;
    bad:           max(0, B - D(a_bad, pred))       push the prediction at least B away from a rejected plan;
    intervention:  D(a_expert, pred)                the continuous-action limit of the ranking constraint:
    with
                   Q = D, "Q(s, a*) < Q(s, a') for every a' != a*" holds exactly when pred = a*, so the
                   explicit term is the regression loss of HG-DAgger (EIL without l_good and l_bad is
                   HG-DAgger); optionally plus ranking_weight * max(0, D(a*, pred) - D(a', pred) + margin)
                   against a recorded contrast action a' (the learner's plan on that step), the paper's
                   pairwise hinge.
B = threshold_b_m ** 2. Each term is summed over its rows and divided by the batch size (the paper's sums,
scaled by 1/N so the learning rate does not depend on the batch size). DEMO rows (BC, DAgger) count as
intervention rows.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from quad_il.data.partitions import PARTITION_CODES, Partition


class LossInputError(ValueError):
    """Bad shapes or non-finite values given to a loss; the message names the argument."""


def _as_points(name: str, x: Tensor) -> Tensor:
    if x.dim() == 2:
        if x.size(1) % 3 != 0:
            raise LossInputError(
                f"{name}: flattened control points need a multiple of 3 columns, got {x.size(1)}"
            )
        x = x.reshape(x.size(0), -1, 3)
    if x.dim() != 3 or x.size(2) != 3:
        raise LossInputError(f"{name}: expected (B, K, 3) or (B, 3K), got {tuple(x.shape)}")
    if not bool(torch.isfinite(x).all()):
        raise LossInputError(f"{name} contains NaN or Inf")
    return x


def mean_sq_ctrl_distance(pred: Tensor, target: Tensor) -> Tensor:
    """D(target, pred) per row: mean over control points of the squared Euclidean distance (B,), in m^2."""
    p = _as_points("pred", pred)
    t = _as_points("target", target)
    if p.shape != t.shape:
        raise LossInputError(f"pred {tuple(p.shape)} and target {tuple(t.shape)} differ in shape")
    return ((p - t) ** 2).sum(dim=2).mean(dim=1)


def eil_good_loss(pred: Tensor, learner_ctrl: Tensor, b_m2: float) -> Tensor:
    """Per-row l_good = max(0, D(a_learner, pred) - B)."""
    return torch.clamp(mean_sq_ctrl_distance(pred, learner_ctrl) - b_m2, min=0.0)


def eil_bad_loss(pred: Tensor, bad_ctrl: Tensor, b_m2: float) -> Tensor:
    """Per-row l_bad = max(0, B - D(a_bad, pred))."""
    return torch.clamp(b_m2 - mean_sq_ctrl_distance(pred, bad_ctrl), min=0.0)


def eil_intervention_loss(
    pred: Tensor,
    expert_ctrl: Tensor,
    contrast_ctrl: Tensor | None = None,
    contrast_mask: Tensor | None = None,
    margin_m2: float = 0.0,
    ranking_weight: float = 0.0,
) -> Tensor:
    """Per-row l_C = D(a*, pred) [+ ranking_weight * max(0, D(a*, pred) - D(a', pred) + margin) where a'
    exists]."""
    d_star = mean_sq_ctrl_distance(pred, expert_ctrl)
    if contrast_ctrl is None or ranking_weight == 0.0:
        return d_star
    d_alt = mean_sq_ctrl_distance(pred, contrast_ctrl)
    hinge = torch.clamp(d_star - d_alt + margin_m2, min=0.0)
    if contrast_mask is not None:
        hinge = hinge * contrast_mask.to(hinge.dtype)
    return d_star + ranking_weight * hinge


@dataclass(frozen=True)
class EILLossTerms:
    total: Tensor
    good: Tensor
    bad: Tensor
    intervention: Tensor


def eil_row_terms(
    pred: Tensor,
    label_ctrl: Tensor,
    partition: Tensor,
    threshold_b_m: float,
    contrast_ctrl: Tensor | None = None,
    contrast_mask: Tensor | None = None,
    ranking_margin_m2: float = 0.0,
    ranking_weight: float = 0.0,
) -> tuple[Tensor, Tensor, Tensor]:
    """Per row (B,) each: l_good on GOOD rows, l_bad on BAD rows, l_C on DEMO/INTERVENTION rows, zero on the
    others; `partition` holds PARTITION_CODES per row (see module docstring)."""
    if not threshold_b_m > 0.0:
        raise LossInputError(f"threshold_b_m must be > 0, got {threshold_b_m}")
    if partition.dim() != 1 or partition.size(0) != pred.size(0):
        raise LossInputError(f"partition must have shape ({pred.size(0)},), got {tuple(partition.shape)}")
    known = torch.tensor(sorted(PARTITION_CODES.values()), device=partition.device)
    if not bool(torch.isin(partition, known).all()):
        raise LossInputError(f"partition holds unknown codes: {sorted(set(partition.tolist()))}")
    b_m2 = threshold_b_m**2
    good_rows = partition == PARTITION_CODES[Partition.GOOD]
    bad_rows = partition == PARTITION_CODES[Partition.BAD]
    int_rows = (partition == PARTITION_CODES[Partition.INTERVENTION]) | (
        partition == PARTITION_CODES[Partition.DEMO]
    )
    zero = pred.new_zeros(pred.size(0))
    l_c = eil_intervention_loss(
        pred, label_ctrl, contrast_ctrl, contrast_mask, ranking_margin_m2, ranking_weight
    )
    return (
        torch.where(good_rows, eil_good_loss(pred, label_ctrl, b_m2), zero),
        torch.where(bad_rows, eil_bad_loss(pred, label_ctrl, b_m2), zero),
        torch.where(int_rows, l_c, zero),
    )


def eil_loss(
    pred: Tensor,
    label_ctrl: Tensor,
    partition: Tensor,
    threshold_b_m: float,
    intervention_weight: float = 1.0,
    contrast_ctrl: Tensor | None = None,
    contrast_mask: Tensor | None = None,
    ranking_margin_m2: float = 0.0,
    ranking_weight: float = 0.0,
) -> EILLossTerms:
    """The EIL objective on a mixed batch: the row terms of `eil_row_terms` summed over the batch and divided
    by its size, lambda = `intervention_weight` on l_C."""
    g, b, c = eil_row_terms(
        pred,
        label_ctrl,
        partition,
        threshold_b_m,
        contrast_ctrl,
        contrast_mask,
        ranking_margin_m2,
        ranking_weight,
    )
    n = pred.size(0)
    good, bad, intervention = g.sum() / n, b.sum() / n, c.sum() / n
    total = good + bad + intervention_weight * intervention
    if not bool(torch.isfinite(total)):
        raise LossInputError("EIL loss is not finite")
    return EILLossTerms(total, good, bad, intervention)
