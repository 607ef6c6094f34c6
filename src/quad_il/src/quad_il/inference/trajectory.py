"""Uniform cubic B-splines as the policy nodes send them (the C++ twin: quad_policy/trajectory.h).

Knots (i - 3) dt for i = 0 .. K + 3: knots[3] = 0 is flown at start_time_s (the depth frame's stamp).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from quad_il.inference.meta import PolicyMeta

FloatArray = NDArray[np.float64]

# Uniform cubic B-spline in matrix form (Qin 2000): p(u) = [1 u u^2 u^3] M [c_k .. c_k+3].
CUBIC_M = np.array([[1, 4, 1, 0], [-3, 0, 3, 0], [3, -6, 3, 0], [-1, 3, -3, 1]], dtype=np.float64) / 6.0


@dataclass(frozen=True)
class UniformBspline:
    start_time_s: float
    knot_dt_s: float
    ctrl_world: FloatArray  # (K, 3), K >= 4
    # None: no yaw (the tracker turns the vehicle along its direction of travel). Else (K,) yaw control points
    # (rad, not wrapped) on the same knots: the tracker flies this heading.
    yaw_ctrl: FloatArray | None = None

    @property
    def num_ctrl_pts(self) -> int:
        return int(self.ctrl_world.shape[0])

    @property
    def duration_s(self) -> float:
        return (self.num_ctrl_pts - 3) * self.knot_dt_s

    def knots(self) -> FloatArray:
        return (np.arange(self.num_ctrl_pts + 4, dtype=np.float64) - 3.0) * self.knot_dt_s

    def _eval(self, t_s: NDArray[np.float64] | float, derivative: int) -> FloatArray:
        if self.num_ctrl_pts < 4 or not self.knot_dt_s > 0.0:
            raise ValueError("a uniform cubic B-spline needs >= 4 control points and knot_dt_s > 0")
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        if not np.all(np.isfinite(t)):
            raise ValueError("B-spline evaluated at a non-finite time")
        segments = self.num_ctrl_pts - 3
        x = np.clip(t / self.knot_dt_s, 0.0, float(segments))
        k = np.minimum(np.floor(x).astype(np.int64), segments - 1)
        u = x - k
        one, zero = np.ones_like(u), np.zeros_like(u)
        if derivative == 0:
            powers = np.stack([one, u, u * u, u * u * u], axis=1)
        elif derivative == 1:
            powers = np.stack([zero, one, 2 * u, 3 * u * u], axis=1) / self.knot_dt_s
        else:
            powers = np.stack([zero, zero, 2 * one, 6 * u], axis=1) / self.knot_dt_s**2
        w = powers @ CUBIC_M  # (S, 4)
        idx = k[:, None] + np.arange(4)[None, :]
        return np.einsum("sj,sjd->sd", w, self.ctrl_world[idx])

    def position(self, t_s: NDArray[np.float64] | float) -> FloatArray:
        """(S, 3) positions at times t_s after start_time_s (clamped to [0, duration])."""
        return self._eval(t_s, 0)

    def velocity(self, t_s: NDArray[np.float64] | float) -> FloatArray:
        return self._eval(t_s, 1)

    def acceleration(self, t_s: NDArray[np.float64] | float) -> FloatArray:
        return self._eval(t_s, 2)

    def velocity_ctrl_pts(self) -> FloatArray:
        """V_i = (c_{i+1} - c_i) / dt: the velocity spline's control points (convex hull bounds the speed)."""
        return np.diff(self.ctrl_world, axis=0) / self.knot_dt_s

    def acceleration_ctrl_pts(self) -> FloatArray:
        return np.diff(self.velocity_ctrl_pts(), axis=0) / self.knot_dt_s


def policy_trajectory(ctrl_world: FloatArray, meta: PolicyMeta, stamp_s: float) -> UniformBspline:
    c = np.asarray(ctrl_world, dtype=np.float64)
    if c.shape != (meta.num_ctrl_pts, 3):
        raise ValueError(
            f"the policy's output has shape {c.shape}, its metadata declares ({meta.num_ctrl_pts}, 3)"
        )
    return UniformBspline(float(stamp_s), meta.knot_dt_s, c)


def _stop_cubic(
    p0: FloatArray, v0: FloatArray, b: FloatArray, duration: float, start_time_s: float
) -> UniformBspline:
    """p(t) = p0 + v0 T / 3 (1 - (1 - t/T)^3) + b (3 (t/T)^2 - 2 (t/T)^3): one cubic, so K = 4 control points
    c_i = P(tau_i) - T^2 / 6 P''(tau_i), tau_i = (i - 1) T, represent it exactly (as the C++ twin)."""
    ctrl = np.empty((4, 3))
    for i in range(4):
        tau = (i - 1) * duration
        u = tau / duration
        r = 1.0 - u
        position = p0 + v0 * (duration / 3.0) * (1.0 - r * r * r) + b * (3.0 * u * u - 2.0 * u * u * u)
        acceleration = -2.0 * v0 * (1.0 - u) / duration + b * (6.0 - 12.0 * u) / (duration * duration)
        ctrl[i] = position - duration * duration / 6.0 * acceleration
    return UniformBspline(float(start_time_s), duration, ctrl)


def _stop_inputs(
    p0_world: FloatArray,
    v0_world: FloatArray,
    max_decel_mps2: float,
    min_duration_s: float,
    start_time_s: float,
) -> tuple[FloatArray, FloatArray]:
    p0 = np.asarray(p0_world, dtype=np.float64)
    v0 = np.asarray(v0_world, dtype=np.float64)
    if not (np.all(np.isfinite(p0)) and np.all(np.isfinite(v0)) and math.isfinite(start_time_s)):
        raise ValueError("stopping trajectory: non-finite start state")
    if not (max_decel_mps2 > 0.0 and min_duration_s > 0.0):
        raise ValueError("stopping trajectory: max_decel_mps2 and min_duration_s must be > 0")
    return p0, v0


def braking_trajectory(
    p0_world: FloatArray,
    v0_world: FloatArray,
    max_decel_mps2: float,
    min_duration_s: float,
    start_time_s: float,
) -> UniformBspline:
    """From p0 with velocity v0 to rest along a line: p(t) = p0 + v0 T / 3 (1 - (1 - t/T)^3) on [0, T], T =
    max(2 |v0| / max_decel, min_duration) (acceleration at most max_decel). One cubic (K = 4)."""
    p0, v0 = _stop_inputs(p0_world, v0_world, max_decel_mps2, min_duration_s, start_time_s)
    duration = max(2.0 * float(np.linalg.norm(v0)) / max_decel_mps2, min_duration_s)
    return _stop_cubic(p0, v0, np.zeros(3), duration, start_time_s)


def turning_stop(
    p0_world: FloatArray,
    v0_world: FloatArray,
    backoff_world: FloatArray,
    yaw0_rad: float,
    rate_radps: float,
    max_decel_mps2: float,
    min_duration_s: float,
    start_time_s: float,
) -> UniformBspline:
    """The stopping trajectory of turning in place (C++ TurningStop): braking_trajectory's motion plus the
    back-off b blended in with s(u) = 3u^2 - 2u^3, and the heading yaw0 + rate t; T = max(2 |v0| /
    max_decel, min_duration, sqrt(6 |b| / max_decel)) keeps the back-off's own acceleration 6 |b| / T^2
    within max_decel."""
    p0, v0 = _stop_inputs(p0_world, v0_world, max_decel_mps2, min_duration_s, start_time_s)
    b = np.asarray(backoff_world, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(b)):
        raise ValueError("turning stop: non-finite back-off")
    duration = max(
        2.0 * float(np.linalg.norm(v0)) / max_decel_mps2,
        min_duration_s,
        math.sqrt(6.0 * float(np.linalg.norm(b)) / max_decel_mps2),
    )
    return with_constant_yaw_rate(_stop_cubic(p0, v0, b, duration, start_time_s), yaw0_rad, rate_radps)


# The final approach's duration search: T = min_duration + k * FINAL_APPROACH_STEP_S, k = 0 .. MAX_STEPS.
FINAL_APPROACH_STEP_S = 0.02
FINAL_APPROACH_MAX_STEPS = 2000


def final_approach(
    p0_world: FloatArray,
    v0_world: FloatArray,
    goal_world: FloatArray,
    max_acc_mps2: float,
    min_duration_s: float,
    start_time_s: float,
) -> UniformBspline | None:
    """The final approach (recovery.final_approach_m; C++ FinalApproach): from p0 with velocity v0 to rest at
    the goal, p(t) = p0 + v0 T / 3 (1 - (1 - u)^3) + b (3 u^2 - 2 u^3), u = t / T, b = goal - p0 - v0 T / 3.
    Its acceleration is linear in u, -2 v0 (1 - u) / T + b (6 - 12 u) / T^2, so largest at an end; T is the
    first of min_duration_s + k * 0.02 s (k = 0 .. 2000) at which both ends are within max_acc_mps2. None
    when no such T exists. One cubic (K = 4)."""
    p0, v0 = _stop_inputs(p0_world, v0_world, max_acc_mps2, min_duration_s, start_time_s)
    g = np.asarray(goal_world, dtype=np.float64).reshape(3)
    if not np.all(np.isfinite(g)):
        raise ValueError("final approach: non-finite goal")
    for k in range(FINAL_APPROACH_MAX_STEPS + 1):
        duration = min_duration_s + k * FINAL_APPROACH_STEP_S
        b = g - p0 - v0 * (duration / 3.0)
        a_start = -2.0 * v0 / duration + 6.0 * b / (duration * duration)
        a_end = -6.0 * b / (duration * duration)
        if max(float(np.linalg.norm(a_start)), float(np.linalg.norm(a_end))) <= max_acc_mps2:
            return _stop_cubic(p0, v0, b, duration, start_time_s)
    return None


def with_constant_yaw_rate(s: UniformBspline, yaw0_rad: float, rate_radps: float) -> UniformBspline:
    """s with a heading that turns at a constant rate, yaw(t) = yaw0 + rate t: a uniform B-spline reproduces a
    linear function exactly with its control points at the Greville abscissae (i - 1) knot_dt_s."""
    if not (math.isfinite(yaw0_rad) and math.isfinite(rate_radps)):
        raise ValueError("with_constant_yaw_rate: non-finite yaw or rate")
    if not (s.knot_dt_s > 0.0 and s.num_ctrl_pts >= 4):
        raise ValueError(
            "with_constant_yaw_rate: the spline needs knot_dt_s > 0 and at least 4 control points"
        )
    yaw = yaw0_rad + rate_radps * (np.arange(s.num_ctrl_pts, dtype=np.float64) - 1.0) * s.knot_dt_s
    return UniformBspline(s.start_time_s, s.knot_dt_s, s.ctrl_world, yaw)
