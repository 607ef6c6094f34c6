"""The intervention gate of HG-DAgger, EIL and MEGA-DAgger: a Schmitt trigger on the learner-expert deviation.

In HG-DAgger (Kelly et al. 2019) a human watches the learner and takes control when it drifts into unsafe or
undesired states, handing control back once the vehicle is back where the learner can cope. Here an expert
planner stands in for the human: it plans on every frame the learner sees, and the gate compares the two
plans.

  learner in control, deviation > on_threshold_m            -> expert takes control (intervention onset)
  expert in control, deviation < off_threshold_m, and the
  intervention has lasted >= min_intervention_steps          -> learner takes control back (release)

off_threshold_m <= on_threshold_m gives hysteresis: between the two thresholds the gate keeps its state, so it
does not chatter when the deviation hovers around one value. An infinite deviation (learner has no plan)
always triggers an intervention.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass


class GateEvent(enum.Enum):
    NONE = "none"
    ONSET = "onset"
    RELEASE = "release"


@dataclass(frozen=True)
class GateParams:
    on_threshold_m: float = 1.0
    off_threshold_m: float = 0.5
    min_intervention_steps: int = 1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.on_threshold_m) and self.on_threshold_m > 0.0):
            raise ValueError(f"on_threshold_m must be finite and > 0, got {self.on_threshold_m}")
        if not (math.isfinite(self.off_threshold_m) and 0.0 <= self.off_threshold_m <= self.on_threshold_m):
            raise ValueError(
                f"off_threshold_m must be in [0, on_threshold_m = {self.on_threshold_m}], "
                f"got {self.off_threshold_m}"
            )
        if self.min_intervention_steps < 1:
            raise ValueError(f"min_intervention_steps must be >= 1, got {self.min_intervention_steps}")


class HysteresisGate:
    """State: intervening or not, and for how many steps. `update` is the pure transition on one deviation."""

    def __init__(self, params: GateParams) -> None:
        self.params = params
        self.intervening = False
        self.steps_in_intervention = 0
        self.onsets = 0

    def reset(self) -> None:
        self.intervening = False
        self.steps_in_intervention = 0

    def update(self, deviation_m: float) -> GateEvent:
        """Feed one step's deviation; returns the transition it caused (the new state is `intervening`)."""
        if math.isnan(deviation_m):
            raise ValueError("gate deviation is NaN")
        p = self.params
        if not self.intervening:
            if deviation_m > p.on_threshold_m:
                self.intervening = True
                self.steps_in_intervention = 1
                self.onsets += 1
                return GateEvent.ONSET
            return GateEvent.NONE
        if self.steps_in_intervention >= p.min_intervention_steps and deviation_m < p.off_threshold_m:
            self.intervening = False
            self.steps_in_intervention = 0
            return GateEvent.RELEASE
        self.steps_in_intervention += 1
        return GateEvent.NONE
