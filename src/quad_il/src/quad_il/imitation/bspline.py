"""B-spline actions and the deviation metric between two of them (ROS-free, numpy only).

An action in quad_il is a B-spline trajectory in the world frame, as in Fast-Planner's `Bspline.msg`: a degree
`order` (3 = cubic), a non-decreasing knot vector with `len(ctrl) + order + 1` entries, control points, and
the absolute time `start_time_s` at which the parameter u = knots[order] is flown (docs/CONVENTIONS.md). The
valid parameter domain is [knots[order], knots[n_ctrl]]; the position at time t is the spline at
u = knots[order] + (t - start_time_s), clamped into the domain (before the start the vehicle is taken to be at
the spline's first point, after the end at its last: what the tracker does when it holds the end of a plan).

Deviation metric (the HG-DAgger / EIL / MEGA-DAgger gate; docs/imitation_learning.md):

  sampled RMS (default)    d(a, b) = sqrt( 1/M * sum_k || p_a(t_k) - p_b(t_k) ||^2 ),
                           t_k = t_obs + k * H / (M - 1), k = 0..M-1, over the horizon H from the observation
                           stamp t_obs. Works for splines with different knots, orders or numbers of points.
  control-point RMS        d(a, b) = sqrt( 1/K * sum_i || P_a,i - P_b,i ||^2 ), for two actions in the same
                           fixed representation (K points each; the learner's output, or the expert resampled
                           to it). Cheap. Since a B-spline is a convex combination of its control points, the
                           pointwise distance of two splines on the same knots never exceeds
                           max_i ||P_a,i - P_b,i||.

Both are in metres. The evaluation is the project's one numpy B-spline module (quad_il.data.bspline, de Boor's
algorithm); this module adds Fast-Planner's clamping of time into the domain and validation with clear
messages; the tests compare against scipy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quad_il.data.bspline import evaluate

FloatArray = NDArray[np.float64]

DeviationMetric = Literal["sampled_rms", "ctrl_rms"]


class SplineError(ValueError):
    """A B-spline is malformed (shape, knots, non-finite values); the message states the bad value."""


def _as_finite(name: str, value: ArrayLike, shape_tail: tuple[int, ...] = ()) -> FloatArray:
    arr = np.array(value, dtype=np.float64, copy=True)
    if shape_tail and (arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail):
        raise SplineError(f"{name} must have shape (N, {', '.join(map(str, shape_tail))}), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise SplineError(f"{name} contains NaN or Inf")
    arr.setflags(write=False)
    return arr


def uniform_knots(num_ctrl: int, order: int, dt_s: float) -> FloatArray:
    """Fast-Planner's uniform knot vector: u_i = (i - order) * dt_s, i = 0..num_ctrl+order; domain [0, (n-p)
    dt]."""
    if order < 1:
        raise SplineError(f"order must be >= 1, got {order}")
    if num_ctrl < order + 1:
        raise SplineError(
            f"a degree-{order} B-spline needs at least {order + 1} control points, got {num_ctrl}"
        )
    if not (np.isfinite(dt_s) and dt_s > 0.0):
        raise SplineError(f"knot interval dt_s must be finite and > 0, got {dt_s}")
    return (np.arange(num_ctrl + order + 1, dtype=np.float64) - order) * float(dt_s)


@dataclass(frozen=True, eq=False)
class SplineAction:
    """One B-spline trajectory (world frame, metres), validated when built. Immutable."""

    ctrl_pts_world: FloatArray
    knots: FloatArray
    order: int = 3
    start_time_s: float = 0.0
    traj_id: int = 0
    _domain: tuple[float, float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        ctrl = _as_finite("ctrl_pts_world", self.ctrl_pts_world, (3,))
        knots = _as_finite("knots", self.knots)
        order = int(self.order)
        if order < 1:
            raise SplineError(f"order must be >= 1, got {self.order}")
        n = ctrl.shape[0]
        if n < order + 1:
            raise SplineError(f"a degree-{order} B-spline needs at least {order + 1} control points, got {n}")
        if knots.ndim != 1 or knots.shape[0] != n + order + 1:
            raise SplineError(
                f"knots must have len(ctrl) + order + 1 = {n + order + 1} entries, got {knots.shape}"
            )
        if np.any(np.diff(knots) < 0.0):
            raise SplineError("knots must be non-decreasing")
        lo, hi = float(knots[order]), float(knots[n])
        if not hi > lo:
            raise SplineError(f"empty parameter domain [{lo}, {hi}]")
        if not np.isfinite(self.start_time_s):
            raise SplineError(f"start_time_s must be finite, got {self.start_time_s}")
        object.__setattr__(self, "ctrl_pts_world", ctrl)
        object.__setattr__(self, "knots", knots)
        object.__setattr__(self, "order", order)
        object.__setattr__(self, "start_time_s", float(self.start_time_s))
        object.__setattr__(self, "traj_id", int(self.traj_id))
        object.__setattr__(self, "_domain", (lo, hi))

    @staticmethod
    def uniform(
        ctrl_pts_world: ArrayLike, dt_s: float, order: int = 3, start_time_s: float = 0.0, traj_id: int = 0
    ) -> SplineAction:
        """A uniform B-spline (Fast-Planner's knots) with knot interval dt_s."""
        ctrl = np.asarray(ctrl_pts_world, dtype=np.float64)
        if ctrl.ndim != 2:
            raise SplineError(f"ctrl_pts_world must have shape (N, 3), got {ctrl.shape}")
        return SplineAction(ctrl, uniform_knots(ctrl.shape[0], order, dt_s), order, start_time_s, traj_id)

    @property
    def num_ctrl(self) -> int:
        return int(self.ctrl_pts_world.shape[0])

    @property
    def duration_s(self) -> float:
        lo, hi = self._domain
        return hi - lo

    @property
    def end_time_s(self) -> float:
        return self.start_time_s + self.duration_s

    def positions(self, times_s: ArrayLike) -> FloatArray:
        """World positions (M, 3) at absolute times (M,), clamped into the spline's time span."""
        t = np.atleast_1d(np.asarray(times_s, dtype=np.float64))
        if not np.all(np.isfinite(t)):
            raise SplineError("evaluation times contain NaN or Inf")
        lo, hi = self._domain
        u = np.clip(lo + (t - self.start_time_s), lo, hi)
        return evaluate(self.knots, self.ctrl_pts_world, self.order, u)

    def same_representation(self, other: SplineAction) -> bool:
        return self.order == other.order and self.num_ctrl == other.num_ctrl

    def allclose(self, other: SplineAction, atol: float = 0.0) -> bool:
        return (
            self.order == other.order
            and self.ctrl_pts_world.shape == other.ctrl_pts_world.shape
            and self.knots.shape == other.knots.shape
            and bool(np.allclose(self.ctrl_pts_world, other.ctrl_pts_world, rtol=0.0, atol=atol))
            and bool(np.allclose(self.knots, other.knots, rtol=0.0, atol=atol))
            and abs(self.start_time_s - other.start_time_s) <= atol
        )


def horizon_times(t_obs_s: float, horizon_s: float, num_samples: int) -> FloatArray:
    """M uniformly spaced absolute times over [t_obs, t_obs + H] (both ends included)."""
    if num_samples < 2:
        raise SplineError(f"num_samples must be >= 2, got {num_samples}")
    if not (np.isfinite(horizon_s) and horizon_s > 0.0):
        raise SplineError(f"horizon_s must be finite and > 0, got {horizon_s}")
    return float(t_obs_s) + np.linspace(0.0, float(horizon_s), int(num_samples))


def sampled_rms_distance(
    a: SplineAction, b: SplineAction, t_obs_s: float, horizon_s: float, num_samples: int
) -> float:
    """RMS of the position distance between a and b sampled over [t_obs, t_obs + horizon] (metres)."""
    t = horizon_times(t_obs_s, horizon_s, num_samples)
    diff = a.positions(t) - b.positions(t)
    return float(np.sqrt(np.mean(np.sum(diff * diff, axis=1))))


def ctrl_rms_distance(a: SplineAction, b: SplineAction) -> float:
    """RMS of the distances of corresponding control points (metres); both must have the same number."""
    if a.num_ctrl != b.num_ctrl:
        raise SplineError(
            f"ctrl_rms needs the same number of control points, got {a.num_ctrl} and {b.num_ctrl}"
        )
    diff = a.ctrl_pts_world - b.ctrl_pts_world
    return float(np.sqrt(np.mean(np.sum(diff * diff, axis=1))))


@dataclass(frozen=True)
class DeviationParams:
    """How the gate measures the distance between the learner's and the expert's plans."""

    metric: DeviationMetric = "sampled_rms"
    horizon_s: float = 2.0
    num_samples: int = 21

    def __post_init__(self) -> None:
        if self.metric not in ("sampled_rms", "ctrl_rms"):
            raise SplineError(f"unknown deviation metric {self.metric!r}")
        horizon_times(0.0, self.horizon_s, self.num_samples)  # validates horizon and samples


def deviation_m(a: SplineAction, b: SplineAction, t_obs_s: float, params: DeviationParams) -> float:
    """The configured deviation metric between two actions, in metres."""
    if params.metric == "ctrl_rms":
        return ctrl_rms_distance(a, b)
    return sampled_rms_distance(a, b, t_obs_s, params.horizon_s, params.num_samples)


def sample_path(action: SplineAction, t_obs_s: float, horizon_s: float, num_samples: int) -> FloatArray:
    """Positions (M, 3) along the action over the horizon from t_obs (used by the safety check)."""
    return action.positions(horizon_times(t_obs_s, horizon_s, num_samples))


def stack_ctrl(actions: Sequence[SplineAction]) -> FloatArray:
    """(N, K, 3) control points of actions that share one representation."""
    if not actions:
        raise SplineError("no actions to stack")
    k = actions[0].num_ctrl
    for i, a in enumerate(actions):
        if a.num_ctrl != k:
            raise SplineError(f"action {i} has {a.num_ctrl} control points, expected {k} like action 0")
    return np.stack([a.ctrl_pts_world for a in actions])
