"""DAgger's mixing coefficient beta per round (Ross, Gordon & Bagnell 2011).

In round i the vehicle is flown by the mixture pi_i = beta_i * expert + (1 - beta_i) * learner_i, and the
expert labels every visited state. Round 0 is usually beta_0 = 1 (pure expert: the behaviour-cloning dataset).
Closed forms (i = round index, 0-based), all floored at beta_min:

  constant     beta_i = beta0
  linear       beta_i = beta0 * max(0, 1 - i / rounds_to_zero)
  exponential  beta_i = beta0 * decay ** i          (Ross et al.'s beta_i = p^(i-1) with 1-based rounds)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

BetaKind = Literal["constant", "linear", "exponential"]


@dataclass(frozen=True)
class BetaSchedule:
    kind: BetaKind = "exponential"
    beta0: float = 1.0
    decay: float = 0.5
    rounds_to_zero: int = 4
    beta_min: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("constant", "linear", "exponential"):
            raise ValueError(f"beta schedule kind must be constant, linear or exponential, got {self.kind!r}")
        if not 0.0 <= self.beta0 <= 1.0:
            raise ValueError(f"beta0 must be in [0, 1], got {self.beta0}")
        if not 0.0 <= self.beta_min <= 1.0:
            raise ValueError(f"beta_min must be in [0, 1], got {self.beta_min}")
        if not 0.0 < self.decay < 1.0:
            raise ValueError(f"decay must be in (0, 1), got {self.decay}")
        if self.rounds_to_zero < 1:
            raise ValueError(f"rounds_to_zero must be >= 1, got {self.rounds_to_zero}")

    def beta(self, round_index: int) -> float:
        if round_index < 0:
            raise ValueError(f"round_index must be >= 0, got {round_index}")
        if self.kind == "constant":
            value = self.beta0
        elif self.kind == "linear":
            value = self.beta0 * max(0.0, 1.0 - round_index / self.rounds_to_zero)
        else:
            value = self.beta0 * math.pow(self.decay, round_index)
        return max(self.beta_min, value)
