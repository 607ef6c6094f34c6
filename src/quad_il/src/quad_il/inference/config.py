"""config/policy.yaml: the configuration of both policy nodes (pydantic v2, strict).

The C++ node reads the same file with quad_common's StrictYaml (quad_policy/config.h): every key is required,
an unknown key, a wrong type or an out-of-range value is a `PolicyConfigError` naming the key and the value.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator


class PolicyConfigError(ValueError):
    """config/policy.yaml is invalid; the message names the key and the value."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class RefusalConfig(_Strict):
    action: Literal["stop", "hover"]
    stop_max_decel_mps2: float = Field(gt=0.0, allow_inf_nan=False)
    stop_min_duration_s: float = Field(gt=0.0, allow_inf_nan=False)


class KeepingConfig(_Strict):
    """Keeping the plan sent before (docs/inference.md, "Keeping the plan"; C++ quad_policy::KeepingConfig). A
    kept plan's rest must pass the test a recovery plan passes (safety.rest_is_clear, with at least
    max(check_horizon_s, stop_min_duration_s) of it left); a stopping trajectory is never kept."""

    # > 0: a plan the node sent is flown on, whatever the new decision, until it is this old (sim time) or its
    # rest fails the test; the network is still asked on every decision. 0: off.
    commit_s: float = Field(ge=0.0, allow_inf_nan=False)
    # A refused decision the recovery finds no plan for sends nothing while the plan sent before passes the
    # test; only when it fails too does the refusal action apply.
    on_refusal: bool


class SafetyConfig(_Strict):
    enabled: bool
    max_vel_mps: float = Field(gt=0.0, allow_inf_nan=False)
    max_acc_mps2: float = Field(gt=0.0, allow_inf_nan=False)
    max_start_error_m: float = Field(gt=0.0, allow_inf_nan=False)
    vehicle_radius_m: float = Field(gt=0.0, allow_inf_nan=False)
    sample_dt_s: float = Field(gt=0.0, allow_inf_nan=False)
    check_horizon_s: float = Field(ge=0.0, allow_inf_nan=False)
    collision_min_pixels: int = Field(ge=1)
    # Depth memory: samples the latest frame does not show are judged by the newest of up to this many earlier
    # decision frames that shows them (0: the latest frame only), kept at least memory_spacing_s apart.
    memory_frames: int = Field(ge=0, le=64)
    memory_spacing_s: float = Field(ge=0.0, allow_inf_nan=False)


class RecoveryConfig(_Strict):
    # On a refused plan, the network is asked again with the goal direction turned about the vehicle's
    # vertical axis by each angle in turn (degrees, +: counter-clockwise seen from above); the first plan the
    # safety layer accepts and that stays in view is sent. Empty: off.
    goal_yaw_offsets_deg: list[float] = Field(max_length=16)
    # Steering: an accepted plan passing nearer than this to what the depth frame shows makes the decider try
    # the same turns; the first that also keeps this distance (and stays in view) replaces it. 0: off; else it
    # must exceed safety.vehicle_radius_m (checked in PolicyNodeConfig).
    steer_clearance_m: float = Field(ge=0.0, allow_inf_nan=False)
    # Turning in place: from this many stopping trajectories in a row (refused, not recovered) on, the stop
    # also turns the heading at turn_rate_dps towards the goal's side, until a plan is sent. 0: off; needs
    # refusal.action stop (checked in PolicyNodeConfig). Not learned: a fixed behaviour of the node.
    turn_after_stops: int = Field(ge=0)
    turn_rate_dps: float = Field(gt=0.0, le=180.0, allow_inf_nan=False)
    # ... and while the depth frame shows a surface nearer than this, the turning stop backs away along the
    # heading by the difference (room to turn). 0: no back-off.
    turn_clearance_m: float = Field(ge=0.0, allow_inf_nan=False)
    # Final approach: within this distance of the goal the node sends a trajectory straight to the goal, to
    # rest there (a cubic with its acceleration within final_approach_acc_mps2), instead of the network's
    # plan, when the safety layer accepts it; else the decision goes on as without it. The expert flies its
    # last metre the same way (fsm.replan_distance_m). 0: off. Not learned: a fixed behaviour of the node.
    final_approach_m: float = Field(ge=0.0, allow_inf_nan=False)
    final_approach_acc_mps2: float = Field(gt=0.0, allow_inf_nan=False)

    @field_validator("goal_yaw_offsets_deg")
    @classmethod
    def _angles(cls, v: list[float]) -> list[float]:
        for a in v:
            if not (math.isfinite(a) and -180.0 <= a <= 180.0 and a != 0.0):
                raise ValueError(f"angles must be finite, non-zero and within [-180, 180] degrees, got {a}")
        return v


class PolicyNodeConfig(_Strict):
    policy_file: str
    num_threads: int = Field(ge=1, le=64)
    replan_rate_hz: float = Field(ge=0.0, allow_inf_nan=False)
    goal_tolerance_m: float = Field(ge=0.0, allow_inf_nan=False)
    max_odom_age_s: float = Field(gt=0.0, allow_inf_nan=False)
    lockstep_consumer: str = Field(min_length=1)
    send_to_tracker: bool
    refusal: RefusalConfig
    recovery: RecoveryConfig
    keeping: KeepingConfig
    safety: SafetyConfig

    @model_validator(mode="after")
    def _steering(self) -> PolicyNodeConfig:
        check_steering(self.recovery, self.safety)
        check_turning(self.recovery, self.refusal)
        return self


def check_steering(recovery: RecoveryConfig, safety: SafetyConfig) -> None:
    """ValueError unless steering is off or has a clearance above the safety radius and turns to try."""
    r = recovery.steer_clearance_m
    if r == 0.0:
        return
    if not r > safety.vehicle_radius_m:
        raise ValueError(
            f"recovery.steer_clearance_m ({r:g}) must be 0 (off) or greater than safety.vehicle_radius_m "
            f"({safety.vehicle_radius_m:g})"
        )
    if not recovery.goal_yaw_offsets_deg:
        raise ValueError(
            "recovery.steer_clearance_m is set but recovery.goal_yaw_offsets_deg is empty: "
            "no turns to steer by"
        )


def check_turning(recovery: RecoveryConfig, refusal: RefusalConfig) -> None:
    """ValueError when turning in place is on without the stopping trajectory it rides on."""
    if recovery.turn_after_stops > 0 and refusal.action != "stop":
        raise ValueError(
            "recovery.turn_after_stops is set but refusal.action is not 'stop' "
            "(the turn rides on the stopping trajectory)"
        )


def config_from_tree(tree: Any, source: str = "<config>") -> PolicyNodeConfig:
    if not isinstance(tree, dict):
        raise PolicyConfigError(f"{source}: top level must be a mapping of keys to values")
    try:
        return PolicyNodeConfig.model_validate(tree)
    except ValidationError as e:
        lines = []
        for err in e.errors():
            key = ".".join(str(p) for p in err["loc"]) or "<root>"
            value = err.get("input")
            shown = "" if isinstance(value, dict) else f" (got {value!r})"
            lines.append(f"key '{key}': {err['msg']}{shown}")
        raise PolicyConfigError(f"{source}: invalid policy config:\n  " + "\n  ".join(lines)) from None


def load_policy_config(path: str | Path) -> PolicyNodeConfig:
    p = Path(path)
    if not p.is_file():
        raise PolicyConfigError(f"policy config not found: {p}")
    try:
        tree = yaml.safe_load(p.read_text())
    except yaml.YAMLError as e:
        raise PolicyConfigError(f"{p}: not valid YAML: {e}") from None
    return config_from_tree(tree, str(p))
