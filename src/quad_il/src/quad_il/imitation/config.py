"""Typed configuration of the interactive imitation-learning algorithms (pydantic v2, unknown keys rejected).

The same models are the `algorithm` section of the manager's YAML (config/il_manager.yaml) and the per-round
`algorithm.yaml` the manager writes for the collector node. `name` selects the algorithm; every key is
documented in docs/imitation_learning.md.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from quad_il.imitation.bspline import DeviationParams
from quad_il.imitation.gate import GateParams
from quad_il.imitation.safety import SafetyParams, ScoreParams
from quad_il.imitation.schedules import BetaSchedule


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class DeviationConfig(_Strict):
    metric: Literal["sampled_rms", "ctrl_rms"] = "sampled_rms"
    horizon_s: float = Field(2.0, gt=0.0)
    num_samples: int = Field(21, ge=2, le=10000)

    def params(self) -> DeviationParams:
        return DeviationParams(self.metric, self.horizon_s, self.num_samples)


class GateConfig(_Strict):
    on_threshold_m: float = Field(1.0, gt=0.0)
    off_threshold_m: float = Field(0.5, ge=0.0)
    min_intervention_steps: int = Field(1, ge=1)
    deviation: DeviationConfig = DeviationConfig()

    @model_validator(mode="after")
    def _hysteresis(self) -> GateConfig:
        if self.off_threshold_m > self.on_threshold_m:
            raise ValueError(
                f"off_threshold_m ({self.off_threshold_m}) must be <= on_threshold_m ({self.on_threshold_m})"
            )
        return self

    def params(self) -> GateParams:
        return GateParams(self.on_threshold_m, self.off_threshold_m, self.min_intervention_steps)


class BetaConfig(_Strict):
    kind: Literal["constant", "linear", "exponential"] = "exponential"
    beta0: float = Field(1.0, ge=0.0, le=1.0)
    decay: float = Field(0.5, gt=0.0, lt=1.0)
    rounds_to_zero: int = Field(4, ge=1)
    beta_min: float = Field(0.0, ge=0.0, le=1.0)
    # per_step: a coin flip with probability beta on every step; per_episode: one flip per episode.
    mixing: Literal["per_step", "per_episode"] = "per_step"

    def schedule(self) -> BetaSchedule:
        return BetaSchedule(self.kind, self.beta0, self.decay, self.rounds_to_zero, self.beta_min)


class BCConfig(_Strict):
    name: Literal["bc"] = "bc"


class DAggerConfig(_Strict):
    name: Literal["dagger"] = "dagger"
    beta: BetaConfig = BetaConfig()


class DARTRangeConfig(_Strict):
    """A closed interval [low, high] a value is drawn from uniformly (low == high: that value)."""

    low: float = Field(ge=0.0)
    high: float = Field(ge=0.0)

    @model_validator(mode="after")
    def _ordered(self) -> DARTRangeConfig:
        if self.high < self.low:
            raise ValueError(f"high ({self.high}) must be >= low ({self.low})")
        return self


class DARTConfig(_Strict):
    """DART (Laskey et al. 2017): the expert flies and labels every step, but during seeded perturbation
    events the plan executed is a disturbed one, so the data covers states off the expert's own path (stopped
    in front of a box, heading beside the expert's line) with the expert's clean label for each
    (docs/imitation_learning.md, "DART"). Needs no learner policy."""

    name: Literal["dart"] = "dart"
    event_rate_per_s: float = Field(0.4, gt=0.0)  # onsets per second of sim time while no event runs
    min_gap_s: float = Field(1.0, ge=0.0)  # unperturbed flight between two events
    first_after_s: float = Field(1.0, ge=0.0)  # no event before this long after the episode's first step
    min_goal_distance_m: float = Field(2.0, ge=0.0)  # no onset this near the goal
    brake_probability: float = Field(0.5, ge=0.0, le=1.0)  # share of brake events; the others veer
    # brake: the executed plan brings the vehicle to rest along its line of motion (deceleration at most
    # brake_decel_mps2) and holds it there; the event lasts brake_duration_s
    brake_decel_mps2: float = Field(3.0, gt=0.0)
    brake_duration_s: DARTRangeConfig = DARTRangeConfig(low=1.0, high=2.5)
    # veer: the expert's plan turned about its start point by an angle drawn from veer_angle_deg (either
    # side, equally likely), for veer_duration_s
    veer_angle_deg: DARTRangeConfig = DARTRangeConfig(low=10.0, high=30.0)
    veer_duration_s: DARTRangeConfig = DARTRangeConfig(low=0.3, high=0.8)
    record_every_steps: int = Field(3, ge=1)  # record every N-th step that has an expert plan
    # a new plan goes to the tracker every N-th step (and at each event's onset); between, the tracker flies
    # the plan sent last. The labeller plans every frame; flown for one frame each, its plans never let the
    # vehicle reach its speed (the expert's own state machine replans about every 1 m, 0.33 s at 3 m/s).
    execute_every_steps: int = Field(10, ge=1)
    # ... and at once, outside events, when the expert's newest plan departs from the plan being flown by more
    # than this (sampled RMS over the next second, m): it saw something, as its state machine replans when its
    # trajectory turns unsafe. 0: off.
    replan_deviation_m: float = Field(0.3, ge=0.0)
    # An episode that ends in a collision loses the records of its last collision_window_s (labels that led
    # into it); records are released at the episode's end.
    collision_window_s: float = Field(1.0, ge=0.0)

    @model_validator(mode="after")
    def _angles(self) -> DARTConfig:
        if self.veer_angle_deg.high > 180.0:
            raise ValueError(f"veer_angle_deg.high must be <= 180, got {self.veer_angle_deg.high}")
        return self


class HGDAggerConfig(_Strict):
    name: Literal["hg_dagger"] = "hg_dagger"
    gate: GateConfig = GateConfig()


class EILLossConfig(_Strict):
    """EIL's training objective (docs/imitation_learning.md, "EIL"); read by the trainer, recorded here."""

    threshold_b_m: float = Field(
        0.5, gt=0.0
    )  # B = threshold_b_m ** 2 on the mean squared control-point distance
    intervention_weight: float = Field(1.0, ge=0.0)  # lambda
    ranking_margin_m2: float = Field(0.0, ge=0.0)
    ranking_weight: float = Field(0.0, ge=0.0)


class EILConfig(_Strict):
    name: Literal["eil"] = "eil"
    gate: GateConfig = GateConfig()
    bad_window_steps: int = Field(3, ge=0, le=1000)
    record_good: bool = True
    loss: EILLossConfig = EILLossConfig()


class MegaSafetyConfig(_Strict):
    min_clearance_m: float = Field(0.3, ge=0.0)
    cbf_gamma: float = Field(0.5, gt=0.0, le=1.0)
    horizon_s: float = Field(2.0, gt=0.0)
    num_samples: int = Field(21, ge=2, le=10000)

    def params(self) -> SafetyParams:
        return SafetyParams(self.min_clearance_m, self.cbf_gamma, self.horizon_s, self.num_samples)


class MegaScoreConfig(_Strict):
    safety_weight: float = Field(0.5, ge=0.0)
    progress_weight: float = Field(0.5, ge=0.0)
    clearance_cap_m: float = Field(2.0, gt=0.0)
    max_speed_mps: float = Field(2.0, gt=0.0)

    def params(self) -> ScoreParams:
        return ScoreParams(self.safety_weight, self.progress_weight, self.clearance_cap_m, self.max_speed_mps)


class MegaConflictConfig(_Strict):
    cosine_threshold: float = Field(0.99, ge=-1.0, le=1.0)
    label_distance_m: float = Field(0.5, ge=0.0)
    horizon_s: float = Field(2.0, gt=0.0)
    num_samples: int = Field(11, ge=2, le=10000)


class MegaDAggerConfig(_Strict):
    name: Literal["mega_dagger"] = "mega_dagger"
    experts: list[str] = Field(default_factory=lambda: ["expert_a", "expert_b"], min_length=1)
    gate_expert: Literal["round_robin", "random"] = "round_robin"
    gate: GateConfig = GateConfig()
    safety: MegaSafetyConfig = MegaSafetyConfig()
    score: MegaScoreConfig = MegaScoreConfig()
    conflict: MegaConflictConfig = MegaConflictConfig()
    collision_window_s: float = Field(1.0, ge=0.0)

    @model_validator(mode="after")
    def _unique_experts(self) -> MegaDAggerConfig:
        if len(set(self.experts)) != len(self.experts):
            raise ValueError(f"experts must be unique names, got {self.experts}")
        if any(not e for e in self.experts):
            raise ValueError("expert names must be non-empty")
        return self


AlgorithmConfig = Annotated[
    BCConfig | DAggerConfig | DARTConfig | HGDAggerConfig | EILConfig | MegaDAggerConfig,
    Field(discriminator="name"),
]


class RoundAlgorithmConfig(_Strict):
    """What the manager hands the collector for one round: the algorithm, the round, the seed, and beta_i."""

    algorithm: AlgorithmConfig
    round_index: int = Field(ge=0)
    seed: int = Field(ge=0)
    beta: float | None = Field(None, ge=0.0, le=1.0)
    # True when there is no learner policy yet (round 0 without an initial policy): the expert flies (BC).
    expert_only: bool = False
