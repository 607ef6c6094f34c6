"""B-spline evaluation (de Boor) and least-squares fitting in numpy, batched over many splines.

Written here rather than taken from scipy because the postprocessing evaluates thousands of splines of
different lengths at once (padded arrays, one vectorised pass) and its arithmetic is part of the documented
format; scipy.interpolate is used only by the tests as an independent reference.
"""

from __future__ import annotations

import numpy as np


def find_spans(knots: np.ndarray, num_ctrl: np.ndarray, degree: int, u: np.ndarray) -> np.ndarray:
    """Knot span index k of each parameter, with knots[k] <= u < knots[k+1] and k in [degree, n-1].

    knots: (B, L) non-decreasing per row (entries past n + degree + 1 are ignored); num_ctrl: (B,) n per row;
    u: (B, S), already inside [knots[degree], knots[n]]. At u == knots[n] the last non-empty span is used.
    """
    b, length = knots.shape
    j = np.arange(length)
    n = num_ctrl.astype(np.int64)[:, None]
    end = np.take_along_axis(knots, n, axis=1)  # knots[n], (B, 1)
    # Count the knots j in [degree+1, n-1] that are <= u and below the domain end: the largest such j is k.
    usable = (j[None, :] >= degree + 1) & (j[None, :] <= n - 1) & (knots < end)  # (B, L)
    below = knots[:, None, :] <= u[:, :, None]  # (B, S, L)
    return degree + np.count_nonzero(below & usable[:, None, :], axis=-1)


def de_boor(
    knots: np.ndarray, ctrl: np.ndarray, num_ctrl: np.ndarray, degree: int, u: np.ndarray
) -> np.ndarray:
    """Evaluates B-splines of one degree with de Boor's algorithm.

    knots: (B, L) float64, ctrl: (B, C, D) control points (rows past num_ctrl ignored), num_ctrl: (B,) int,
    u: (B, S) parameters inside each spline's domain [knots[degree], knots[n]]. Returns (B, S, D).
    """
    knots = np.asarray(knots, dtype=np.float64)
    ctrl = np.asarray(ctrl, dtype=np.float64)
    u = np.asarray(u, dtype=np.float64)
    p = int(degree)
    if p < 0:
        raise ValueError(f"degree {p} must be >= 0")
    if np.any(num_ctrl < p + 1):
        raise ValueError(f"every spline needs at least degree + 1 = {p + 1} control points")
    k = find_spans(knots, num_ctrl, p, u)  # (B, S)
    bidx = np.arange(knots.shape[0])[:, None]  # (B, 1)
    # d[j] = P[k - p + j], j = 0..p  -> (B, S, p+1, D)
    d = np.stack([ctrl[bidx, k - p + jj] for jj in range(p + 1)], axis=2)
    for r in range(1, p + 1):
        for jj in range(p, r - 1, -1):
            i = k - p + jj
            left = knots[bidx, i]
            right = knots[bidx, i + p + 1 - r]
            alpha = ((u - left) / (right - left))[..., None]
            d[:, :, jj] = (1.0 - alpha) * d[:, :, jj - 1] + alpha * d[:, :, jj]
    return d[:, :, p]


def evaluate(knots: np.ndarray, ctrl: np.ndarray, degree: int, u: np.ndarray) -> np.ndarray:
    """One spline: knots (n + degree + 1,), ctrl (n, D), u (S,) -> (S, D)."""
    ctrl = np.asarray(ctrl, dtype=np.float64)
    if ctrl.ndim == 1:
        ctrl = ctrl[:, None]
    knots = np.asarray(knots, dtype=np.float64)
    if knots.shape[0] != ctrl.shape[0] + degree + 1:
        raise ValueError(f"{knots.shape[0]} knots for {ctrl.shape[0]} control points of degree {degree}")
    return de_boor(knots[None], ctrl[None], np.array([ctrl.shape[0]]), degree, np.asarray(u)[None])[0]


def uniform_knots(num_ctrl: int, degree: int, knot_dt: float) -> np.ndarray:
    """Knots (i - degree) * knot_dt, i = 0..num_ctrl + degree: the domain is [0, (num_ctrl - degree) * dt]."""
    return (np.arange(num_ctrl + degree + 1, dtype=np.float64) - degree) * knot_dt


def basis_matrix(knots: np.ndarray, num_ctrl: int, degree: int, u: np.ndarray) -> np.ndarray:
    """(S, num_ctrl) matrix A with A[s, i] = N_i(u_s), computed by de Boor on identity control points."""
    identity = np.eye(num_ctrl)
    return evaluate(knots, identity, degree, u)


def fit_matrix(num_ctrl: int, degree: int, knot_dt: float, u: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of the uniform basis matrix: control points = fit_matrix @ samples (least squares)."""
    a = basis_matrix(uniform_knots(num_ctrl, degree, knot_dt), num_ctrl, degree, u)
    if np.linalg.matrix_rank(a) < num_ctrl:
        raise ValueError("sample parameters do not determine every control point (rank-deficient fit)")
    return np.linalg.pinv(a)
