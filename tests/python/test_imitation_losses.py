"""EIL's losses on predicted vs label B-splines: hand-computed values, gradients' direction, bad input."""

from __future__ import annotations

import math

import pytest
import torch

from quad_il.data.partitions import PARTITION_CODES, Partition
from quad_il.learning.eil import (
    LossInputError,
    eil_bad_loss,
    eil_good_loss,
    eil_intervention_loss,
    eil_loss,
    mean_sq_ctrl_distance,
)

GOOD, BAD, INT, DEMO = (
    PARTITION_CODES[p] for p in (Partition.GOOD, Partition.BAD, Partition.INTERVENTION, Partition.DEMO)
)


def pts(*rows: list[list[float]]) -> torch.Tensor:
    return torch.tensor(rows, dtype=torch.float64)


def test_mean_squared_control_point_distance_by_hand() -> None:
    pred = pts([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    target = pts([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    assert mean_sq_ctrl_distance(pred, target).item() == pytest.approx((1 + 4) / 2)
    # The flattened (B, 3K) layout of the network output is the same thing.
    assert mean_sq_ctrl_distance(pred.reshape(1, -1), target.reshape(1, -1)).item() == pytest.approx(2.5)


def test_good_and_bad_hinges_by_hand() -> None:
    pred = torch.zeros(2, 2, 3, dtype=torch.float64)
    far = pts([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]], [[0.6, 0.0, 0.0], [0.0, 0.6, 0.0]])  # D = 2.5 and 0.36
    b_m2 = 1.0
    torch.testing.assert_close(eil_good_loss(pred, far, b_m2), torch.tensor([1.5, 0.0], dtype=torch.float64))
    torch.testing.assert_close(eil_bad_loss(pred, far, b_m2), torch.tensor([0.0, 0.64], dtype=torch.float64))


def test_intervention_loss_with_and_without_the_ranking_hinge() -> None:
    pred = torch.zeros(2, 1, 3, dtype=torch.float64)
    expert = pts([[2.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]])  # D* = 4, 1
    contrast = pts([[1.0, 0.0, 0.0]], [[0.0, 0.0, 3.0]])  # D' = 1, 9
    torch.testing.assert_close(
        eil_intervention_loss(pred, expert), torch.tensor([4.0, 1.0], dtype=torch.float64)
    )
    ranked = eil_intervention_loss(pred, expert, contrast, margin_m2=0.5, ranking_weight=2.0)
    # Row 0: hinge max(0, 4 - 1 + 0.5) = 3.5 -> 4 + 7 = 11; row 1: max(0, 1 - 9 + 0.5) = 0 -> 1.
    torch.testing.assert_close(ranked, torch.tensor([11.0, 1.0], dtype=torch.float64))
    masked = eil_intervention_loss(
        pred, expert, contrast, torch.tensor([False, True]), margin_m2=0.5, ranking_weight=2.0
    )
    torch.testing.assert_close(masked, torch.tensor([4.0, 1.0], dtype=torch.float64))


def test_eil_objective_on_a_mixed_batch_by_hand() -> None:
    pred = torch.zeros(4, 1, 3, dtype=torch.float64)
    label = pts(
        [[2.0, 0.0, 0.0]], [[0.5, 0.0, 0.0]], [[0.0, 1.0, 0.0]], [[0.0, 0.0, 3.0]]
    )  # D = 4, .25, 1, 9
    part = torch.tensor([GOOD, BAD, INT, DEMO])
    terms = eil_loss(pred, label, part, threshold_b_m=1.0, intervention_weight=0.5)
    # good: max(0, 4 - 1) = 3; bad: max(0, 1 - 0.25) = 0.75; intervention rows: 1 + 9 = 10; all / N = 4.
    assert terms.good.item() == pytest.approx(3 / 4)
    assert terms.bad.item() == pytest.approx(0.75 / 4)
    assert terms.intervention.item() == pytest.approx(10 / 4)
    assert terms.total.item() == pytest.approx((3 + 0.75 + 0.5 * 10) / 4)


def test_gradient_steps_move_predictions_the_way_each_partition_asks() -> None:
    label = pts([[1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]])
    part = torch.tensor([GOOD, BAD, INT])
    pred = torch.tensor([[[3.0, 0.0, 0.0]], [[1.2, 0.0, 0.0]], [[3.0, 0.0, 0.0]]], dtype=torch.float64)
    pred.requires_grad_(True)
    before = mean_sq_ctrl_distance(pred.detach(), label)
    eil_loss(pred, label, part, threshold_b_m=1.0).total.backward()
    with torch.no_grad():
        after = mean_sq_ctrl_distance(pred - 0.05 * pred.grad, label)
    assert after[0] < before[0]  # good: back within B of the accepted plan
    assert after[1] > before[1]  # bad: away from the rejected plan
    assert after[2] < before[2]  # intervention: towards the expert
    # A good row already within B and a bad row already beyond B give no gradient.
    calm = torch.tensor([[[1.5, 0.0, 0.0]], [[3.0, 0.0, 0.0]]], dtype=torch.float64, requires_grad=True)
    eil_loss(calm, label[:2], part[:2], threshold_b_m=1.0).total.backward()
    assert torch.count_nonzero(calm.grad) == 0


def test_bad_input_is_rejected_with_the_argument_named() -> None:
    ok = torch.zeros(2, 4, 3)
    with pytest.raises(LossInputError, match="pred contains NaN or Inf"):
        mean_sq_ctrl_distance(torch.full((2, 4, 3), math.nan), ok)
    with pytest.raises(LossInputError, match=r"pred \(2, 4, 3\) and target \(2, 5, 3\) differ"):
        mean_sq_ctrl_distance(ok, torch.zeros(2, 5, 3))
    with pytest.raises(LossInputError, match="multiple of 3 columns, got 7"):
        mean_sq_ctrl_distance(torch.zeros(2, 7), torch.zeros(2, 7))
    with pytest.raises(LossInputError, match=r"unknown codes: \[0, 9\]"):
        eil_loss(ok, ok, torch.tensor([0, 9]), threshold_b_m=1.0)
    with pytest.raises(LossInputError, match="threshold_b_m must be > 0"):
        eil_loss(ok, ok, torch.tensor([0, 1]), threshold_b_m=0.0)
