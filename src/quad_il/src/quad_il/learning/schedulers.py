"""Learning-rate schedulers of the thesis (section 3.9, Tables 3.2 and 3.3), stepped once per optimiser step.

`CustomCosineDecayRestarts`: cosine decay with warm restarts (Loshchilov & Hutter, "SGDR", ICLR 2017) in the
form of TensorFlow's `CosineDecayRestarts`, which the thesis's parameter names follow. With step t, first
period T_0 (`first_decay_steps`), period multiplier t_mul, peak multiplier m_mul and floor alpha (fraction of
the initial lr):

    f = t / T_0
    restart i = floor(f)                                   if t_mul == 1
              = floor(log(1 - f (1 - t_mul)) / log t_mul)  otherwise
    position in period x = f - i                           if t_mul == 1
                         = (f - (1 - t_mul^i) / (1 - t_mul)) / t_mul^i  otherwise
    lr(t) = lr_0 * ((1 - alpha) * 0.5 * m_mul^i * (1 + cos(pi x)) + alpha)

Period i lasts T_0 * t_mul^i steps; its peak is lr_0 * (alpha + (1 - alpha) m_mul^i); the floor is alpha *
lr_0. Thesis values: T_0 = 50000, t_mul = 1.5, alpha = 0.01; the thesis gives no m_mul, so 1.0 (TF's default).

`pytorch` is PyTorch's own `CosineAnnealingWarmRestarts` (thesis: T_0 500, T_mult 1, eta_min 1e-5).

`cosine` is the same closed form with a single period spanning the whole run (T_0 = the run's optimiser steps,
t_mul = m_mul = 1): the rate falls from lr_0 to alpha lr_0 by the last step. With the thesis's T_0 = 50000 a
run of 10 epochs over 20k samples (6250 steps) ends at 96 % of lr_0, so its last weights are as noisy as its
first epochs' (docs/learning.md, "Schedulers").
"""

from __future__ import annotations

import math

from torch.optim import Optimizer
from torch.optim.lr_scheduler import CosineAnnealingWarmRestarts, LRScheduler

from quad_il.learning.config import SchedulerConfig


def cosine_decay_restarts_factor(
    step: int, first_decay_steps: int, t_mul: float = 1.5, m_mul: float = 1.0, alpha: float = 0.01
) -> float:
    """lr(step) / lr_0 of the formula in the module docstring."""
    if step < 0:
        raise ValueError(f"step must be >= 0, got {step}")
    if first_decay_steps < 1 or t_mul < 1.0 or not 0.0 < m_mul <= 1.0 or not 0.0 <= alpha <= 1.0:
        raise ValueError(
            f"invalid cosine-restart parameters: first_decay_steps={first_decay_steps}, t_mul={t_mul}, "
            f"m_mul={m_mul}, alpha={alpha}"
        )
    f = step / first_decay_steps
    if t_mul == 1.0:
        i = math.floor(f)
        x = f - i
    else:
        i = math.floor(math.log(1.0 - f * (1.0 - t_mul)) / math.log(t_mul))
        start = (1.0 - t_mul**i) / (1.0 - t_mul)
        x = (f - start) / t_mul**i
        # Guard the floor() against rounding at period boundaries: x must lie in [0, 1).
        if x >= 1.0:
            i, x = i + 1, (f - (1.0 - t_mul ** (i + 1)) / (1.0 - t_mul)) / t_mul ** (i + 1)
        elif x < 0.0:
            i, x = i - 1, (f - (1.0 - t_mul ** (i - 1)) / (1.0 - t_mul)) / t_mul ** (i - 1)
    cosine = 0.5 * m_mul**i * (1.0 + math.cos(math.pi * x))
    return (1.0 - alpha) * cosine + alpha


class CustomCosineDecayRestarts(LRScheduler):
    """Cosine decay with warm restarts, closed form in the step count (resumable through `state_dict`)."""

    def __init__(
        self,
        optimizer: Optimizer,
        first_decay_steps: int = 50000,
        t_mul: float = 1.5,
        m_mul: float = 1.0,
        alpha: float = 0.01,
        last_epoch: int = -1,
    ) -> None:
        cosine_decay_restarts_factor(0, first_decay_steps, t_mul, m_mul, alpha)  # validates the parameters
        self.first_decay_steps = first_decay_steps
        self.t_mul = t_mul
        self.m_mul = m_mul
        self.alpha = alpha
        super().__init__(optimizer, last_epoch)

    def factor(self, step: int) -> float:
        return cosine_decay_restarts_factor(step, self.first_decay_steps, self.t_mul, self.m_mul, self.alpha)

    def get_lr(self) -> list[float]:  # type: ignore[override]
        f = self.factor(max(self.last_epoch, 0))
        return [base * f for base in self.base_lrs]

    def _get_closed_form_lr(self) -> list[float]:
        return self.get_lr()


def build_scheduler(
    cfg: SchedulerConfig, optimizer: Optimizer, total_steps: int | None = None
) -> LRScheduler | None:
    """The configured scheduler; `cosine` needs the run's number of optimiser steps (total_steps)."""
    if cfg.name == "none":
        return None
    if cfg.name == "cosine":
        if total_steps is None or total_steps < 1:
            raise ValueError(f"scheduler 'cosine' needs the run's optimiser steps >= 1, got {total_steps}")
        return CustomCosineDecayRestarts(optimizer, total_steps, 1.0, 1.0, cfg.cosine.alpha)
    if cfg.name == "custom":
        c = cfg.custom
        return CustomCosineDecayRestarts(optimizer, c.first_decay_steps, c.t_mul, c.m_mul, c.alpha)
    if cfg.name == "pytorch":
        p = cfg.pytorch
        return CosineAnnealingWarmRestarts(optimizer, T_0=p.T_0, T_mult=p.T_mult, eta_min=p.eta_min)
    raise ValueError(f"scheduler.name must be custom, pytorch, cosine or none, got {cfg.name!r}")
