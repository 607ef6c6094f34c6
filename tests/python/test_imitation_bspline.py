"""B-spline evaluation and the learner-expert deviation metric (quad_il.imitation.bspline)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.interpolate import BSpline

from quad_il.imitation.bspline import (
    DeviationParams,
    SplineAction,
    SplineError,
    ctrl_rms_distance,
    deviation_m,
    sampled_rms_distance,
    uniform_knots,
)


@pytest.mark.parametrize("order", [1, 2, 3, 4, 5])
def test_de_boor_matches_scipy_inside_the_domain(order: int) -> None:
    rng = np.random.default_rng(order)
    ctrl = rng.normal(size=(order + 6, 3))
    dt = 0.3
    action = SplineAction.uniform(ctrl, dt, order=order, start_time_s=10.0)
    ref = BSpline(uniform_knots(ctrl.shape[0], order, dt), ctrl, order)
    u = np.linspace(0.0, action.duration_s, 57)
    np.testing.assert_allclose(action.positions(10.0 + u), ref(u), rtol=0, atol=1e-12)


def test_non_uniform_knots_match_scipy() -> None:
    rng = np.random.default_rng(7)
    ctrl = rng.normal(size=(7, 3))
    knots = np.cumsum(np.r_[0.0, rng.uniform(0.1, 1.0, size=10)])
    action = SplineAction(ctrl, knots, order=3, start_time_s=-2.0)
    ref = BSpline(knots, ctrl, 3)
    u = np.linspace(knots[3], knots[7], 41)
    np.testing.assert_allclose(action.positions(-2.0 + (u - knots[3])), ref(u), rtol=0, atol=1e-12)


def test_times_outside_the_span_are_clamped_to_the_end_points() -> None:
    action = SplineAction.uniform(np.arange(18.0).reshape(6, 3), 0.5, start_time_s=1.0)
    first, last = action.positions([1.0, action.end_time_s])
    np.testing.assert_allclose(action.positions([-100.0])[0], first)
    np.testing.assert_allclose(action.positions([1e6])[0], last)


def test_uniform_knots_follow_fast_planner() -> None:
    np.testing.assert_allclose(uniform_knots(5, 3, 0.5), [-1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0, 2.5])
    assert SplineAction.uniform(np.zeros((8, 3)), 0.4).duration_s == pytest.approx(2.0)


def test_collinear_equally_spaced_points_give_constant_velocity() -> None:
    # Cubic uniform B-spline of P_i = a + i b: p(u) = a + b (1 + u / dt).
    a, b, dt = np.array([-0.8, 0.0, 1.0]), np.array([0.8, 0.0, 0.0]), 0.4
    action = SplineAction.uniform(a + np.arange(8)[:, None] * b, dt)
    u = np.linspace(0.0, 2.0, 9)
    np.testing.assert_allclose(action.positions(u), a + (1.0 + u / dt)[:, None] * b, atol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"ctrl_pts_world": np.full((5, 3), np.nan), "knots": uniform_knots(5, 3, 0.1)}, "NaN or Inf"),
        ({"ctrl_pts_world": np.zeros((5, 2)), "knots": uniform_knots(5, 3, 0.1)}, r"shape \(N, 3\)"),
        ({"ctrl_pts_world": np.zeros((5, 3)), "knots": np.arange(8.0)}, "len\\(ctrl\\) \\+ order \\+ 1 = 9"),
        ({"ctrl_pts_world": np.zeros((5, 3)), "knots": np.arange(9.0)[::-1].copy()}, "non-decreasing"),
        ({"ctrl_pts_world": np.zeros((3, 3)), "knots": np.arange(7.0)}, "at least 4 control points"),
        ({"ctrl_pts_world": np.zeros((5, 3)), "knots": np.zeros(9)}, "empty parameter domain"),
    ],
)
def test_malformed_splines_are_rejected_with_the_reason(kwargs: dict, message: str) -> None:
    with pytest.raises(SplineError, match=message):
        SplineAction(**kwargs)


def test_uniform_rejects_a_non_positive_knot_interval() -> None:
    with pytest.raises(SplineError, match="dt_s must be finite and > 0, got 0.0"):
        SplineAction.uniform(np.zeros((5, 3)), 0.0)


def test_evaluating_at_nan_time_is_an_error() -> None:
    with pytest.raises(SplineError, match="evaluation times"):
        SplineAction.uniform(np.zeros((5, 3)), 0.1).positions([math.nan])


def test_deviation_of_a_translated_spline_is_the_translation_length() -> None:
    rng = np.random.default_rng(3)
    ctrl = rng.normal(size=(9, 3))
    offset = np.array([0.3, -0.4, 1.2])  # |offset| = 1.3
    a = SplineAction.uniform(ctrl, 0.25, start_time_s=5.0)
    b = SplineAction.uniform(ctrl + offset, 0.25, start_time_s=5.0)
    assert ctrl_rms_distance(a, b) == pytest.approx(1.3, abs=1e-12)
    assert sampled_rms_distance(a, b, 5.0, 1.5, 31) == pytest.approx(1.3, abs=1e-12)
    assert sampled_rms_distance(b, a, 5.0, 1.5, 31) == pytest.approx(1.3, abs=1e-12)
    assert deviation_m(a, a, 5.0, DeviationParams()) == 0.0


def test_ctrl_rms_is_the_root_mean_square_of_point_distances() -> None:
    a = SplineAction.uniform(np.zeros((4, 3)), 0.5)
    b = SplineAction.uniform([[1.0, 0, 0], [0, 2.0, 0], [0, 0, 0], [0, 0, 2.0]], 0.5)
    assert ctrl_rms_distance(a, b) == pytest.approx(math.sqrt((1 + 4 + 0 + 4) / 4))


def test_sampled_rms_of_a_time_shifted_constant_velocity_path_is_speed_times_shift() -> None:
    # p(t) = v t inside the domain; b starts 0.1 s later, so b(t) = a(t - 0.1): distance |v| * 0.1 everywhere.
    v = np.array([2.0, 0.0, 0.0])
    dt = 0.2
    ctrl = (np.arange(20)[:, None] - 1.0) * v * dt  # p(u) = v * u for this cubic uniform spline
    a = SplineAction.uniform(ctrl, dt, start_time_s=0.0)
    b = SplineAction.uniform(ctrl, dt, start_time_s=0.1)
    assert sampled_rms_distance(a, b, t_obs_s=0.5, horizon_s=2.0, num_samples=11) == pytest.approx(
        0.2, abs=1e-12
    )


def test_sampled_rms_compares_splines_with_different_knots_and_sizes() -> None:
    # The same straight segment as a 6-point and a 12-point uniform spline: the deviation is zero.
    v, t_end = np.array([1.0, 0.5, 0.0]), 2.0
    a = SplineAction.uniform((np.arange(6)[:, None] - 1.0) * v * (t_end / 3), t_end / 3)
    b = SplineAction.uniform((np.arange(12)[:, None] - 1.0) * v * (t_end / 9), t_end / 9)
    assert sampled_rms_distance(a, b, 0.0, t_end, 21) == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(SplineError, match="same number of control points, got 6 and 12"):
        ctrl_rms_distance(a, b)


def test_deviation_params_are_validated() -> None:
    with pytest.raises(SplineError, match="unknown deviation metric"):
        DeviationParams(metric="l1")  # type: ignore[arg-type]
    with pytest.raises(SplineError, match="num_samples must be >= 2"):
        DeviationParams(num_samples=1)
    with pytest.raises(SplineError, match="horizon_s must be finite and > 0"):
        DeviationParams(horizon_s=-1.0)
