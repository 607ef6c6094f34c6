"""Value types of the interactive imitation-learning core: observations, paired actions, decisions, records.

Everything is an immutable dataclass validated when built (shapes, finiteness), so a malformed message is
rejected where it enters (the rospy collector converts messages into these and logs the reason of a
rejection). Frames and units follow docs/CONVENTIONS.md: world ENU metres, quaternions (x, y, z, w).
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quad_il.data.partitions import Partition
from quad_il.imitation.bspline import SplineAction

FloatArray = NDArray[np.float64]


class ImitationError(ValueError):
    """Invalid input to the imitation core; the message names the field and the value."""


class Controller(enum.Enum):
    """Who flies the vehicle on a step."""

    EXPERT = "expert"
    LEARNER = "learner"
    NONE = "none"  # neither has a usable plan: the tracker holds the previous one


CONTROLLER_CODES: dict[Controller, int] = {Controller.EXPERT: 0, Controller.LEARNER: 1, Controller.NONE: 2}


def _vec(name: str, value: ArrayLike, n: int) -> FloatArray:
    arr = np.array(value, dtype=np.float64, copy=True).reshape(-1)
    if arr.shape != (n,):
        raise ImitationError(f"{name} must have {n} elements, got shape {np.shape(value)}")
    if not np.all(np.isfinite(arr)):
        raise ImitationError(f"{name} contains NaN or Inf: {arr.tolist()}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Observation:
    """What the policy and the expert saw on one depth frame (the lockstep frame identified by frame_seq)."""

    stamp_s: float
    frame_seq: int
    episode_id: int
    p_world_body: FloatArray
    v_world: FloatArray
    q_world_body: FloatArray  # (x, y, z, w)
    goal_world: FloatArray
    depth_m: NDArray[np.float32] | None = None  # (H, W) metres, as published; None in scripted tests
    features: FloatArray | None = None  # observation descriptor for MEGA-DAgger's similarity matching
    odom_stamp_s: float = float("nan")  # stamp of the odometry the state came from (NaN: unknown)

    def __post_init__(self) -> None:
        if not np.isfinite(self.stamp_s):
            raise ImitationError(f"stamp_s must be finite, got {self.stamp_s}")
        object.__setattr__(self, "stamp_s", float(self.stamp_s))
        object.__setattr__(self, "frame_seq", int(self.frame_seq))
        object.__setattr__(self, "odom_stamp_s", float(self.odom_stamp_s))
        object.__setattr__(self, "episode_id", int(self.episode_id))
        object.__setattr__(self, "p_world_body", _vec("p_world_body", self.p_world_body, 3))
        object.__setattr__(self, "v_world", _vec("v_world", self.v_world, 3))
        q = _vec("q_world_body", self.q_world_body, 4)
        norm = float(np.linalg.norm(q))
        if not 0.5 < norm < 1.5:
            raise ImitationError(f"q_world_body must be a unit quaternion (x, y, z, w), norm is {norm:.3f}")
        object.__setattr__(self, "q_world_body", q)
        object.__setattr__(self, "goal_world", _vec("goal_world", self.goal_world, 3))
        if self.depth_m is not None:
            d = np.array(self.depth_m, dtype=np.float32, copy=True)
            if d.ndim != 2 or d.size == 0:
                raise ImitationError(f"depth_m must be a non-empty (H, W) image, got shape {d.shape}")
            d.setflags(write=False)
            object.__setattr__(self, "depth_m", d)
        if self.features is not None:
            f = np.array(self.features, dtype=np.float64, copy=True).reshape(-1)
            if f.size == 0 or not np.all(np.isfinite(f)):
                raise ImitationError("features must be a non-empty finite vector")
            f.setflags(write=False)
            object.__setattr__(self, "features", f)


@dataclass(frozen=True, eq=False)
class Pair:
    """One observation with the plans made from exactly it: the learner's and every expert's (None = no plan).

    `experts` maps expert name -> plan; single-expert algorithms use `primary_expert` (default "expert").
    """

    obs: Observation
    learner: SplineAction | None
    experts: Mapping[str, SplineAction | None]
    primary_expert: str = "expert"

    def __post_init__(self) -> None:
        if not self.experts:
            raise ImitationError("a pair needs at least one expert entry (its plan may be None)")
        if self.primary_expert not in self.experts:
            raise ImitationError(
                f"primary_expert {self.primary_expert!r} not among experts {sorted(self.experts)}"
            )
        object.__setattr__(self, "experts", dict(self.experts))

    @staticmethod
    def single(obs: Observation, expert: SplineAction | None, learner: SplineAction | None) -> Pair:
        return Pair(obs=obs, learner=learner, experts={"expert": expert})

    @property
    def expert(self) -> SplineAction | None:
        return self.experts[self.primary_expert]


@dataclass(frozen=True, eq=False)
class Record:
    """One training sample: the observation, the label the loss uses, and why it was recorded.

    `label` is the target action (expert plan for DEMO/INTERVENTION; learner plan for EIL's GOOD/BAD).
    `contrast` is an alternative action for ranking losses (EIL: the learner's plan on an intervention step).
    `score` is MEGA-DAgger's safety/progress score of the label (NaN when not computed).
    """

    obs: Observation
    label: SplineAction
    partition: Partition
    source: str  # "learner" or the expert's name
    controller: Controller  # who flew on this step
    round_index: int
    deviation_m: float = float("nan")  # learner-expert deviation on this step (NaN if unknown)
    contrast: SplineAction | None = None
    score: float = float("nan")
    min_clearance_m: float = float("nan")


@dataclass(frozen=True, eq=False)
class Decision:
    """The callback's answer for one pair: who flies, which plan is executed, what is recorded now.

    `records` may include records of earlier steps (EIL emits a step only once it knows whether an
    intervention followed); `intervening` reports the gate state after this step.
    """

    controller: Controller
    action: SplineAction | None
    records: tuple[Record, ...] = ()
    expert_name: str | None = None  # which expert flies when controller is EXPERT
    intervening: bool = False
    deviation_m: float = float("nan")


@dataclass(frozen=True)
class EpisodeOutcome:
    """How an episode ended, from the simulator's EpisodeStatus."""

    reached_goal: bool = False
    collided: bool = False
    collision_time_s: float | None = None
    reason: str = ""


@dataclass
class LearnerStats:
    """Counters of one learner over its lifetime (reported by the collector and the manager)."""

    steps: int = 0
    steps_expert: int = 0
    steps_learner: int = 0
    steps_none: int = 0
    interventions: int = 0
    records: dict[str, int] = field(default_factory=lambda: {p.value: 0 for p in Partition})
    dropped_unsafe: int = 0
    dropped_conflict: int = 0
    dropped_collision: int = 0
    missing_expert: int = 0
    missing_learner: int = 0

    def count_records(self, records: tuple[Record, ...] | list[Record]) -> None:
        for r in records:
            self.records[r.partition.value] += 1
