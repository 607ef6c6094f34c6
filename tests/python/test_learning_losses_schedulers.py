"""Losses (thesis eq. 3.1, 3.2) and learning-rate schedulers (Tables 3.2, 3.3) vs hand-computed values."""

from __future__ import annotations

import math

import pytest
import torch
from torch.optim.lr_scheduler import CosineAnnealingWarmRestarts

from quad_il.learning.config import SchedulerConfig
from quad_il.learning.losses import (
    batch_loss,
    mse_per_sample,
    per_sample_loss,
    sse_per_sample,
    wta_per_sample,
)
from quad_il.learning.schedulers import (
    CustomCosineDecayRestarts,
    build_scheduler,
    cosine_decay_restarts_factor,
)


# ----------------------------------------------------------------------------------------------------- losses
def test_mse_and_sse_equal_hand_computed_values() -> None:
    expert = torch.tensor([[1.0, 2.0, 3.0, 4.0], [0.0, 0.0, 0.0, 0.0]])
    learned = torch.tensor([[1.0, 0.0, 4.0, 4.0], [1.0, -1.0, 2.0, 0.5]])
    # Sample 0: errors 0, 2, -1, 0 -> SSE 5, MSE 5/4; sample 1: 1, 1, 4, 0.25 -> SSE 6.25, MSE 1.5625.
    torch.testing.assert_close(sse_per_sample(learned, expert), torch.tensor([5.0, 6.25]))
    torch.testing.assert_close(mse_per_sample(learned, expert), torch.tensor([1.25, 1.5625]))
    mean, per = batch_loss("sse", learned, expert)
    assert mean.item() == pytest.approx(5.625) and per.shape == (2,)
    assert batch_loss("mse", learned, expert)[0].item() == pytest.approx((1.25 + 1.5625) / 2)


def test_losses_flatten_control_point_arrays() -> None:
    a = torch.zeros(3, 10, 3)
    b = torch.ones(3, 10, 3) * 2
    torch.testing.assert_close(mse_per_sample(a, b), torch.full((3,), 4.0))
    torch.testing.assert_close(sse_per_sample(a, b), torch.full((3,), 120.0))


def test_loss_gradients_match_the_closed_form() -> None:
    learned = torch.tensor([[0.5, -1.0, 2.0]], requires_grad=True)
    expert = torch.tensor([[1.0, 1.0, 1.0]])
    batch_loss("mse", learned, expert)[0].backward()
    torch.testing.assert_close(learned.grad, 2 * (learned.detach() - expert) / 3)
    learned.grad = None
    batch_loss("sse", learned, expert)[0].backward()
    torch.testing.assert_close(learned.grad, 2 * (learned.detach() - expert))


def test_loss_rejects_bad_inputs() -> None:
    with pytest.raises(ValueError, match="shape"):
        mse_per_sample(torch.zeros(2, 3), torch.zeros(2, 4))
    with pytest.raises(ValueError, match="'mse' or 'sse'"):
        per_sample_loss("mae", torch.zeros(2, 3), torch.zeros(2, 3))  # type: ignore[arg-type]


def test_relaxed_winner_takes_all_by_hand() -> None:
    target = torch.tensor([[0.0, 0.0], [1.0, 1.0]])
    # Sample 0: hypothesis MSEs 1, 0.25, 4 -> winner 1; sample 1: 0, 1, 1 -> winner 0.
    plans = torch.tensor(
        [
            [[1.0, 1.0], [0.5, -0.5], [2.0, 2.0]],
            [[1.0, 1.0], [2.0, 0.0], [0.0, 2.0]],
        ]
    )
    logits = torch.tensor([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    per, winner = wta_per_sample("mse", plans, logits, target, relax=0.1, confidence_weight=0.5)
    assert winner.tolist() == [1, 0]
    ce0 = math.log(3.0)  # uniform logits
    ce1 = -math.log(math.exp(2.0) / (math.exp(2.0) + 2.0))
    expected0 = 0.9 * 0.25 + 0.05 * (1.0 + 4.0) + 0.5 * ce0
    expected1 = 0.9 * 0.0 + 0.05 * (1.0 + 1.0) + 0.5 * ce1
    torch.testing.assert_close(per, torch.tensor([expected0, expected1]))
    # SSE per hypothesis is MSE times the width; no relaxation and no confidence term: the winner's loss only.
    sse, _ = wta_per_sample("sse", plans, logits, target, relax=0.0, confidence_weight=0.0)
    torch.testing.assert_close(sse, torch.tensor([0.5, 0.0]))


def test_winner_takes_all_trains_only_the_winner_and_the_logits() -> None:
    target = torch.tensor([[0.0, 0.0]])
    plans = torch.tensor([[[1.0, 1.0], [0.5, -0.5]]], requires_grad=True)
    logits = torch.zeros(1, 2, requires_grad=True)
    per, _ = wta_per_sample("mse", plans, logits, target, relax=0.0, confidence_weight=1.0)
    per.sum().backward()
    assert not plans.grad[0, 0].any()  # the loser gets nothing without relaxation
    torch.testing.assert_close(plans.grad[0, 1], torch.tensor([0.5, -0.5]))  # d/dx mean(x^2) = x
    torch.testing.assert_close(logits.grad, torch.tensor([[0.5, -0.5]]))  # softmax - one_hot(winner 1)


def test_winner_takes_all_keeps_two_modes_that_one_plan_averages() -> None:
    """The same input labelled left (+1) half of the time and right (-1) the other half, as the expert passes
    a box on either side: one plan learns the average, straight through the box; two hypotheses learn both."""
    target = torch.tensor([[1.0, 0.5], [-1.0, 0.5]]).repeat(8, 1)

    def fit(m: int) -> torch.Tensor:
        torch.manual_seed(0)
        plans = torch.nn.Parameter(0.1 * torch.randn(1, m, 2))
        logits = torch.nn.Parameter(torch.zeros(1, m))
        opt = torch.optim.Adam([plans, logits], lr=0.05)
        for _ in range(400):
            opt.zero_grad()
            p = plans.expand(len(target), m, 2)
            if m == 1:
                loss = batch_loss("mse", p[:, 0], target)[0]
            else:
                loss = wta_per_sample("mse", p, logits.expand(len(target), m), target, 0.05, 0.1)[0].mean()
            loss.backward()
            opt.step()
        return plans.detach()[0]

    single = fit(1)
    torch.testing.assert_close(single[0], torch.tensor([0.0, 0.5]), atol=0.02, rtol=0)
    pair = fit(2)
    firsts = sorted(float(x) for x in pair[:, 0])
    # Each wins half the samples: 0.95 (x - 1) + 0.05 (x + 1) = 0, so the relaxation leaves them at -+0.9.
    assert firsts == pytest.approx([-0.9, 0.9], abs=0.02)
    torch.testing.assert_close(pair[:, 1], torch.tensor([0.5, 0.5]), atol=0.02, rtol=0)


def test_winner_takes_all_rejects_bad_inputs() -> None:
    plans, logits, target = torch.zeros(2, 3, 4), torch.zeros(2, 3), torch.zeros(2, 4)
    with pytest.raises(ValueError, match="expected plans"):
        wta_per_sample("mse", plans, logits, torch.zeros(2, 5), 0.05, 0.1)
    with pytest.raises(ValueError, match="at least 2 hypotheses"):
        wta_per_sample("mse", plans[:, :1], logits[:, :1], target, 0.05, 0.1)
    with pytest.raises(ValueError, match="relax must be in"):
        wta_per_sample("mse", plans, logits, target, 1.0, 0.1)


# ------------------------------------------------------------------------------------------------- schedulers
def test_custom_schedule_with_the_thesis_values_at_hand_computed_steps() -> None:
    # T_0 = 50000, t_mul = 1.5, alpha = 0.01, m_mul = 1: lr/lr0 = 0.01 + 0.99 * 0.5 * (1 + cos(pi x)).
    f = lambda step: cosine_decay_restarts_factor(step, 50000, 1.5, 1.0, 0.01)  # noqa: E731
    assert f(0) == pytest.approx(1.0)
    assert f(25000) == pytest.approx(0.505)  # x = 1/2
    assert f(12500) == pytest.approx(0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi / 4)))
    assert f(49999) == pytest.approx(0.01 + 0.99 * 0.5 * (1 + math.cos(math.pi * 49999 / 50000)))
    assert f(50000) == pytest.approx(1.0)  # first restart
    assert f(50000 + 37500) == pytest.approx(0.505)  # second period lasts 75000 steps
    assert f(125000) == pytest.approx(1.0)  # second restart at 50000 + 75000
    assert f(125000 + 112500 // 2) == pytest.approx(0.505)  # third period lasts 112500 steps


def test_custom_schedule_restart_peaks_decay_by_m_mul_and_floor_is_alpha() -> None:
    f = lambda step: cosine_decay_restarts_factor(step, 10, 2.0, 0.5, 0.1)  # noqa: E731
    # Periods of 10, 20, 40 steps; peaks 1, 0.5, 0.25 of the cosine part; floor 0.1.
    assert f(0) == pytest.approx(1.0)
    assert f(5) == pytest.approx(0.1 + 0.9 * 0.5)
    assert f(10) == pytest.approx(0.1 + 0.9 * 0.5)
    assert f(20) == pytest.approx(0.1 + 0.9 * 0.5 * 0.5)  # halfway through the second period
    assert f(30) == pytest.approx(0.1 + 0.9 * 0.25)
    assert f(50) == pytest.approx(0.1 + 0.9 * 0.25 * 0.5)
    assert min(f(s) for s in range(200)) >= 0.1


def test_custom_schedule_with_t_mul_one_is_periodic() -> None:
    f = lambda step: cosine_decay_restarts_factor(step, 7, 1.0, 1.0, 0.0)  # noqa: E731
    for s in range(30):
        assert f(s) == pytest.approx(0.5 * (1 + math.cos(math.pi * (s % 7) / 7)))


def test_custom_scheduler_drives_the_optimizer_learning_rate() -> None:
    param = torch.nn.Parameter(torch.zeros(1))
    opt = torch.optim.SGD([param], lr=0.2)
    sched = CustomCosineDecayRestarts(opt, first_decay_steps=10, t_mul=1.5, m_mul=0.8, alpha=0.01)
    for step in range(60):
        assert opt.param_groups[0]["lr"] == pytest.approx(
            0.2 * cosine_decay_restarts_factor(step, 10, 1.5, 0.8)
        )
        opt.step()
        sched.step()


def test_custom_scheduler_resumes_from_its_state_dict() -> None:
    def run(steps: int, restore: dict | None = None) -> tuple[list[float], dict]:
        opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
        sched = CustomCosineDecayRestarts(opt, 8, 1.5, 0.9, 0.05)
        if restore is not None:
            sched.load_state_dict(restore)
            for g in opt.param_groups:
                g["lr"] = sched.get_last_lr()[0]
        lrs = []
        for _ in range(steps):
            opt.step()
            sched.step()
            lrs.append(opt.param_groups[0]["lr"])
        return lrs, sched.state_dict()

    full, _ = run(30)
    first, state = run(12)
    second, _ = run(18, state)
    assert first + second == pytest.approx(full)


def test_invalid_custom_scheduler_parameters_are_rejected() -> None:
    with pytest.raises(ValueError, match="t_mul=0.5"):
        cosine_decay_restarts_factor(0, 10, 0.5)
    with pytest.raises(ValueError, match="step must be >= 0"):
        cosine_decay_restarts_factor(-1, 10)


def test_pytorch_scheduler_with_the_thesis_values_matches_the_closed_form() -> None:
    # Table 3.2: T_0 = 500, T_mult = 1, eta_min = 1e-5:
    #   lr(t) = eta_min + (lr0 - eta_min) (1 + cos(pi (t mod 500) / 500)) / 2
    opt = torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=1e-3)
    sched = build_scheduler(SchedulerConfig(name="pytorch"), opt)
    assert isinstance(sched, CosineAnnealingWarmRestarts)
    hand = {
        0: 1e-3,
        125: 1e-5 + (1e-3 - 1e-5) * (1 + math.cos(math.pi / 4)) / 2,
        250: 1e-5 + (1e-3 - 1e-5) / 2,
        499: 1e-5 + (1e-3 - 1e-5) * (1 + math.cos(math.pi * 499 / 500)) / 2,
        500: 1e-3,
        750: 1e-5 + (1e-3 - 1e-5) / 2,
    }
    for step in range(751):
        if step in hand:
            assert opt.param_groups[0]["lr"] == pytest.approx(hand[step], rel=1e-9), step
        opt.step()
        sched.step()


def test_scheduler_factory() -> None:
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    assert build_scheduler(SchedulerConfig(name="none"), opt) is None
    custom = build_scheduler(SchedulerConfig(name="custom"), opt)
    assert isinstance(custom, CustomCosineDecayRestarts)
    assert (custom.first_decay_steps, custom.t_mul, custom.alpha) == (50000, 1.5, 0.01)


def test_cosine_scheduler_decays_once_over_the_whole_run() -> None:
    # lr(t) = lr0 ((1 - alpha) (1 + cos(pi t / T)) / 2 + alpha), T = the run's steps: lr0 at the first step,
    # half-way at T / 2, alpha lr0 + (1 - alpha) lr0 (1 + cos(pi (T - 1) / T)) / 2 at the last step.
    opt = torch.optim.Adam([torch.nn.Parameter(torch.zeros(1))], lr=1e-3)
    sched = build_scheduler(SchedulerConfig(name="cosine"), opt, total_steps=200)
    lrs = []
    for _ in range(200):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert lrs[0] == pytest.approx(1e-3)
    assert lrs[100] == pytest.approx(1e-3 * (0.99 * 0.5 + 0.01))
    assert lrs[199] == pytest.approx(1e-3 * (0.99 * 0.5 * (1 + math.cos(math.pi * 199 / 200)) + 0.01))
    assert lrs[199] < 1.1e-5
    assert all(b <= a for a, b in zip(lrs, lrs[1:], strict=False))


def test_cosine_scheduler_needs_the_run_length() -> None:
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    with pytest.raises(ValueError, match="needs the run's optimiser steps >= 1, got None"):
        build_scheduler(SchedulerConfig(name="cosine"), opt)
