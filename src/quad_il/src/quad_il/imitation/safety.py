"""MEGA-DAgger's data filter and label score (Sun et al. 2023, "MEGA-DAgger: Imitation Learning with Multiple
Imperfect Experts"), adapted from racing to quadrotor flight among obstacles.

Safety check of a label (a B-spline over the horizon H from the observation stamp), sampled at M points p_k:
  h_k = clearance(p_k) - min_clearance_m                      (a barrier function: h >= 0 is the safe set)
  safe  <=>  h_k >= 0 for all k   and   h_{k+1} >= (1 - gamma) h_k for all k
The second condition is the discrete-time control-barrier-function condition (the paper filters demonstrations
with a CBF): the barrier may shrink by at most the fraction gamma in (0, 1] per sample interval H / (M - 1),
so a label that dives towards an obstacle is rejected before it touches the clearance limit. gamma = 1 keeps
only h >= 0.

Score of a safe label (the paper resolves conflicting labels with a score that weighs safety and progress):
  safety   s = clip(min_k clearance(p_k) / clearance_cap_m, 0, 1)
  progress g = clip((|p_body - goal| - |p(t_obs + H) - goal|) / (max_speed_mps * H), -1, 1)
  score    w = safety_weight * s + progress_weight * g

Clearance comes from a `ClearanceMap`; `PointCloudClearance` answers it from the occupied voxels of the world
(the simulator's latched /sim/voxel_map) with a k-d tree.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quad_il.imitation.bspline import SplineAction, horizon_times
from quad_il.imitation.types import ImitationError, Observation

FloatArray = NDArray[np.float64]


class ClearanceMap(Protocol):
    def clearance_m(self, points_world: FloatArray) -> FloatArray:
        """Distance (metres, >= 0) from each point (M, 3) to the nearest obstacle surface."""
        ...


class PointCloudClearance:
    """Clearance to a set of occupied voxels (centres, world frame), each a cube of side voxel_size_m.

    clearance(p) = max(0, |p - nearest centre| - voxel_size_m / 2): exact for the face-nearest voxel, a slight
    under-estimate (conservative by at most (sqrt(3) - 1) / 2 voxel) towards edges and corners. An empty cloud
    has infinite clearance.
    """

    def __init__(self, occupied_world: ArrayLike, voxel_size_m: float) -> None:
        pts = np.asarray(occupied_world, dtype=np.float64).reshape(-1, 3)
        if not np.all(np.isfinite(pts)):
            raise ImitationError("occupied voxel centres contain NaN or Inf")
        if not (math.isfinite(voxel_size_m) and voxel_size_m > 0.0):
            raise ImitationError(f"voxel_size_m must be finite and > 0, got {voxel_size_m}")
        self.voxel_size_m = float(voxel_size_m)
        from scipy.spatial import cKDTree  # imported here: the manager imports this module and needs no scipy

        self._tree = cKDTree(pts) if pts.shape[0] else None

    def clearance_m(self, points_world: FloatArray) -> FloatArray:
        q = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        if self._tree is None:
            return np.full(q.shape[0], np.inf)
        dist, _ = self._tree.query(q)
        return np.maximum(0.0, dist - 0.5 * self.voxel_size_m)


class WorldClearance:
    """The clearance of whichever world is current: the collector `update`s it with each world's map (the
    simulator publishes one at every reset). Before the first map nothing is known, so every point has
    clearance 0 (every label is unsafe) and `queries_without_map` counts the queries."""

    def __init__(self) -> None:
        self._map: ClearanceMap | None = None
        self.updates = 0
        self.queries_without_map = 0

    def update(self, world: ClearanceMap) -> None:
        self._map = world
        self.updates += 1

    def clearance_m(self, points_world: FloatArray) -> FloatArray:
        if self._map is None:
            self.queries_without_map += 1
            return np.zeros(np.asarray(points_world).reshape(-1, 3).shape[0])
        return self._map.clearance_m(points_world)


@dataclass(frozen=True)
class SafetyParams:
    min_clearance_m: float = 0.3
    cbf_gamma: float = 0.5
    horizon_s: float = 2.0
    num_samples: int = 21

    def __post_init__(self) -> None:
        if not (math.isfinite(self.min_clearance_m) and self.min_clearance_m >= 0.0):
            raise ValueError(f"min_clearance_m must be finite and >= 0, got {self.min_clearance_m}")
        if not 0.0 < self.cbf_gamma <= 1.0:
            raise ValueError(f"cbf_gamma must be in (0, 1], got {self.cbf_gamma}")
        horizon_times(0.0, self.horizon_s, self.num_samples)


@dataclass(frozen=True)
class ScoreParams:
    safety_weight: float = 0.5
    progress_weight: float = 0.5
    clearance_cap_m: float = 2.0
    max_speed_mps: float = 2.0

    def __post_init__(self) -> None:
        if self.safety_weight < 0.0 or self.progress_weight < 0.0:
            raise ValueError("score weights must be >= 0")
        if self.safety_weight + self.progress_weight <= 0.0:
            raise ValueError("at least one score weight must be > 0")
        if not self.clearance_cap_m > 0.0:
            raise ValueError(f"clearance_cap_m must be > 0, got {self.clearance_cap_m}")
        if not self.max_speed_mps > 0.0:
            raise ValueError(f"max_speed_mps must be > 0, got {self.max_speed_mps}")


@dataclass(frozen=True)
class SafetyResult:
    safe: bool
    min_clearance_m: float
    reason: str  # empty when safe


def check_label_safety(
    action: SplineAction, t_obs_s: float, clearance: ClearanceMap, params: SafetyParams
) -> SafetyResult:
    """The clearance + discrete CBF check of one label over the horizon (see the module docstring)."""
    times = horizon_times(t_obs_s, params.horizon_s, params.num_samples)
    c = np.asarray(clearance.clearance_m(action.positions(times)), dtype=np.float64)
    if c.shape != times.shape or np.any(np.isnan(c)):
        raise ImitationError(f"clearance map returned an invalid result of shape {c.shape}")
    min_c = float(np.min(c))
    h = c - params.min_clearance_m
    below = np.flatnonzero(h < 0.0)
    if below.size:
        k = int(below[0])
        return SafetyResult(
            False,
            min_c,
            f"clearance {c[k]:.3f} m < {params.min_clearance_m:.3f} m at t_obs + {times[k] - t_obs_s:.2f} s",
        )
    # Barrier decay condition; infinite clearance (no obstacle in range) never violates it.
    finite = np.isfinite(h[:-1]) & np.isfinite(h[1:])
    violated = np.flatnonzero(finite & (h[1:] < (1.0 - params.cbf_gamma) * h[:-1] - 1e-12))
    if violated.size:
        k = int(violated[0])
        return SafetyResult(
            False,
            min_c,
            f"CBF condition h[k+1] >= (1 - {params.cbf_gamma}) h[k] violated at t_obs + "
            f"{times[k + 1] - t_obs_s:.2f} s (h {h[k]:.3f} -> {h[k + 1]:.3f} m)",
        )
    return SafetyResult(True, min_c, "")


def label_score(
    action: SplineAction, obs: Observation, min_clearance_m: float, horizon_s: float, params: ScoreParams
) -> float:
    """MEGA-DAgger's score of a label: weighted safety (clearance) and progress towards the goal."""
    safety = (
        min(1.0, max(0.0, min_clearance_m / params.clearance_cap_m))
        if math.isfinite(min_clearance_m)
        else 1.0
    )
    p_end = action.positions([obs.stamp_s + horizon_s])[0]
    d0 = float(np.linalg.norm(obs.p_world_body - obs.goal_world))
    d1 = float(np.linalg.norm(p_end - obs.goal_world))
    progress = max(-1.0, min(1.0, (d0 - d1) / (params.max_speed_mps * horizon_s)))
    return params.safety_weight * safety + params.progress_weight * progress
