"""Offline metrics between expert and learned B-splines (thesis section 4.5, Table 4.1), per sample.

Inputs are control-point sets (N, K, 3) in metres, in one frame. Definitions (also in docs/learning.md):

* MSE: mean over the 3K elements of the flattened sets of the squared difference (m^2), equation (3.1).
* Cosine similarity: a.b / (|a| |b|) of the flattened sets (1 for both zero, 0 when exactly one is zero).
* Bhattacharyya distance, two forms:
  - `bhattacharyya_flat`, the thesis's form: the thesis compares the distributions of the 3K values of the
    flattened control-point vectors (its helper binned them into 50-bin histograms, and summed only 8 of the
    bins). Here each flattened vector's values get a Gaussian fit, mean m and ML variance s^2 (ddof 0), and
        D_B = (m_1 - m_2)^2 / (4 (s_1^2 + s_2^2)) + 1/2 ln((s_1^2 + s_2^2) / (2 s_1 s_2)),
    the closed form for two 1-D Gaussians. A fit instead of a histogram because 3K = 30 values in 50 bins
    leave most bins empty or single, and the histogram's value then jumps as a value crosses a bin edge.
    Like the thesis's, it compares value distributions only: it does not see which coordinate a value
    belongs to or the order of the points (MSE and the point-set form do).
  - `bhattacharyya_points`: Gaussian fits of the two sets of K points in 3-D. Each set gets the maximum-
    likelihood mean mu and covariance S = (1/K) sum (x - mu)(x - mu)^T, regularised as S + r I with r =
    `reg_m2` (default 0.01 m^2, i.e. a 0.1 m standard deviation floor: the planner's map resolution, and what
    keeps the nearly collinear control points of a straight flight from giving singular covariances). With
    S = (S_1 + S_2) / 2:
        D_B = 1/8 (mu_1 - mu_2)^T S^-1 (mu_1 - mu_2) + 1/2 ln(det S / sqrt(det S_1 det S_2)).
    It has no counterpart in the thesis; its scale is set by r (a 0.1 m offset across the flight direction
    alone gives 1/8).
  Both are symmetric, >= 0, and 0 exactly when the two fits are identical.

MSE and the point-set D_B are invariant under a rigid motion applied to both sets (so equal in the world and
local frames); the cosine similarity and the flattened D_B are not: in the world frame (the thesis's) both are
dominated by the absolute position.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import stats

DEFAULT_BHATTACHARYYA_REG_M2 = 0.01


def _check_pair(
    a: NDArray[np.floating], b: NDArray[np.floating]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    a64 = np.asarray(a, dtype=np.float64)
    b64 = np.asarray(b, dtype=np.float64)
    if a64.shape != b64.shape or a64.ndim != 3 or a64.shape[2] != 3:
        raise ValueError(f"expected two (N, K, 3) arrays of equal shape, got {a64.shape} and {b64.shape}")
    if not (np.isfinite(a64).all() and np.isfinite(b64).all()):
        raise ValueError("control points contain NaN or Inf")
    return a64, b64


def mse(a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float64]:
    a64, b64 = _check_pair(a, b)
    return ((a64 - b64) ** 2).reshape(len(a64), -1).mean(axis=1)


def cosine_similarity(a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float64]:
    a64, b64 = _check_pair(a, b)
    fa = a64.reshape(len(a64), -1)
    fb = b64.reshape(len(b64), -1)
    na = np.linalg.norm(fa, axis=1)
    nb = np.linalg.norm(fb, axis=1)
    dot = (fa * fb).sum(axis=1)
    out = np.zeros(len(fa))
    both = (na > 0) & (nb > 0)
    out[both] = np.clip(dot[both] / (na[both] * nb[both]), -1.0, 1.0)
    out[(na == 0) & (nb == 0)] = 1.0
    return out


def gaussian_fit(
    points: NDArray[np.floating], reg_m2: float
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(N, K, 3) -> mean (N, 3), regularised ML covariance (N, 3, 3)."""
    p = np.asarray(points, dtype=np.float64)
    mu = p.mean(axis=1)
    d = p - mu[:, None, :]
    cov = np.einsum("nki,nkj->nij", d, d) / p.shape[1]
    return mu, cov + reg_m2 * np.eye(3)


def bhattacharyya_flat(a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float64]:
    """D_B between 1-D Gaussian fits of the values of each flattened control-point vector (thesis form).

    A vector whose values are all equal has variance 0: two such vectors with the same value give 0, any
    other pair involving one gives +inf (the Gaussians' overlap is then zero or undefined)."""
    a64, b64 = _check_pair(a, b)
    fa = a64.reshape(len(a64), -1)
    fb = b64.reshape(len(b64), -1)
    m1, m2 = fa.mean(axis=1), fb.mean(axis=1)
    v1, v2 = fa.var(axis=1), fb.var(axis=1)
    out = np.full(len(fa), np.inf)
    ok = (v1 > 0) & (v2 > 0)
    vs = v1[ok] + v2[ok]
    out[ok] = (m1[ok] - m2[ok]) ** 2 / (4.0 * vs) + 0.5 * np.log(vs / (2.0 * np.sqrt(v1[ok] * v2[ok])))
    out[(v1 == 0) & (v2 == 0) & (m1 == m2)] = 0.0
    # Non-negative in exact arithmetic (AM >= GM); remove rounding noise of order 1e-16 only.
    return np.where(np.abs(out) < 1e-12, np.abs(out), out)


def bhattacharyya_points(
    a: NDArray[np.floating], b: NDArray[np.floating], reg_m2: float = DEFAULT_BHATTACHARYYA_REG_M2
) -> NDArray[np.float64]:
    """D_B between regularised 3-D Gaussian fits of the two sets of K control points."""
    if not reg_m2 > 0.0:
        raise ValueError(f"reg_m2 must be > 0 (covariances of collinear points are singular), got {reg_m2}")
    a64, b64 = _check_pair(a, b)
    mu1, s1 = gaussian_fit(a64, reg_m2)
    mu2, s2 = gaussian_fit(b64, reg_m2)
    s = 0.5 * (s1 + s2)
    dmu = mu1 - mu2
    maha = np.einsum("ni,ni->n", dmu, np.linalg.solve(s, dmu[..., None])[..., 0])
    logdet = np.linalg.slogdet(s)[1]
    logdet1 = np.linalg.slogdet(s1)[1]
    logdet2 = np.linalg.slogdet(s2)[1]
    d = 0.125 * maha + 0.5 * (logdet - 0.5 * (logdet1 + logdet2))
    # Non-negative in exact arithmetic; remove rounding noise of order 1e-16 only.
    return np.where(np.abs(d) < 1e-12, np.abs(d), d)


@dataclass(frozen=True)
class MeanCI:
    mean: float
    half_width: float  # 95 % confidence interval: mean +- half_width (Student t)
    n: int

    def __str__(self) -> str:
        return f"{self.mean:.5g} ± {self.half_width:.2g}"


def mean_ci95(values: NDArray[np.floating]) -> MeanCI:
    """Mean and half-width of its two-sided 95 % confidence interval (t distribution, n - 1 dof)."""
    v = np.asarray(values, dtype=np.float64)
    if v.ndim != 1 or len(v) == 0:
        raise ValueError("need a non-empty 1-D array")
    if len(v) == 1:
        return MeanCI(float(v[0]), float("nan"), 1)
    sem = float(v.std(ddof=1) / np.sqrt(len(v)))
    return MeanCI(float(v.mean()), float(stats.t.ppf(0.975, len(v) - 1) * sem), len(v))
