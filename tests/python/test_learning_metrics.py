"""Offline metrics on constructed cases, and the evaluation script's outputs."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from quad_il.learning import metrics
from quad_il.learning.config import ModelConfig
from quad_il.learning.evaluation import evaluate
from quad_il.learning.export import export_torchscript, policy_metadata
from quad_il.learning.model import build_policy
from quad_il.learning.synthetic import write_synthetic_npz

ROOT = Path(__file__).resolve().parents[2]


def spline(k: int = 10, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2, k)
    return np.stack([2 * t, np.sin(t) + rng.normal(0, 0.1, k), 0.3 * t], axis=1)[None]


# ------------------------------------------------------------------------------------------ constructed cases
def test_identical_splines_give_mse_0_cosine_1_bhattacharyya_0() -> None:
    a = np.concatenate([spline(seed=s) for s in range(4)])
    assert np.array_equal(metrics.mse(a, a), np.zeros(4))
    np.testing.assert_allclose(metrics.cosine_similarity(a, a), np.ones(4), rtol=0, atol=1e-15)
    assert np.array_equal(metrics.bhattacharyya_points(a, a), np.zeros(4))
    assert np.array_equal(metrics.bhattacharyya_flat(a, a), np.zeros(4))


def test_mse_of_a_shift_along_one_axis() -> None:
    a = spline()
    b = a + np.array([0.6, 0.0, 0.0])
    # Every control point's x differs by 0.6 m: K * 0.36 over 3K elements.
    assert metrics.mse(a, b)[0] == pytest.approx(0.36 / 3)


def test_cosine_similarity_of_parallel_opposite_and_orthogonal_sets() -> None:
    a = spline()
    assert metrics.cosine_similarity(a, 2.5 * a)[0] == pytest.approx(1.0)
    assert metrics.cosine_similarity(a, -a)[0] == pytest.approx(-1.0)
    x = np.zeros((1, 4, 3))
    x[0, :, 0] = 1.0
    y = np.zeros((1, 4, 3))
    y[0, :, 1] = 3.0
    assert metrics.cosine_similarity(x, y)[0] == pytest.approx(0.0)
    zero = np.zeros((1, 4, 3))
    assert metrics.cosine_similarity(zero, zero)[0] == 1.0
    assert metrics.cosine_similarity(zero, x)[0] == 0.0


def _square(sigma: float) -> np.ndarray:
    """4 points with mean 0 and ML covariance diag(sigma^2, sigma^2, 0)."""
    return np.array([[[sigma, 0, 0], [-sigma, 0, 0], [0, sigma, 0], [0, -sigma, 0]]]) * math.sqrt(2)


def test_bhattacharyya_of_shifted_sets_is_the_mahalanobis_term() -> None:
    reg = 0.01
    a = _square(0.5)
    cov = np.diag([0.25 + reg, 0.25 + reg, reg])
    np.testing.assert_allclose(metrics.gaussian_fit(a, reg)[1][0], cov, atol=1e-12)
    d = np.array([0.3, 0.0, 0.05])
    b = a + d
    expected = 0.125 * (0.09 / (0.25 + reg) + 0.0025 / reg)  # same covariances: no log-det term
    assert metrics.bhattacharyya_points(a, b, reg)[0] == pytest.approx(expected)


def test_bhattacharyya_of_scaled_sets_is_the_log_det_term() -> None:
    reg = 0.01
    s1, s2 = 0.25 + reg, 1.0 + reg  # variances in x and y; z has reg only in both
    expected = 0.5 * 2 * math.log(((s1 + s2) / 2) / math.sqrt(s1 * s2))
    assert metrics.bhattacharyya_points(_square(0.5), _square(1.0), reg)[0] == pytest.approx(expected)


def test_flat_bhattacharyya_of_shifted_values_is_the_mean_term() -> None:
    a = spline()
    d = 0.4
    var = a.reshape(-1).var()
    # Every value moves by d: equal variances, so only (m1 - m2)^2 / (4 (v + v)) remains.
    assert metrics.bhattacharyya_flat(a, a + d)[0] == pytest.approx(d**2 / (8 * var))


def test_flat_bhattacharyya_of_scaled_values_is_the_variance_term() -> None:
    a = spline() - spline().reshape(-1).mean()  # values with mean 0: scaling keeps the mean
    c = 1.7
    expected = 0.5 * math.log((1 + c**2) / (2 * c))
    assert metrics.bhattacharyya_flat(a, c * a)[0] == pytest.approx(expected)


def test_flat_bhattacharyya_of_constant_vectors() -> None:
    x = np.full((1, 4, 3), 2.0)
    assert metrics.bhattacharyya_flat(x, x)[0] == 0.0
    assert metrics.bhattacharyya_flat(x, x + 1.0)[0] == math.inf
    assert metrics.bhattacharyya_flat(x, spline(k=4))[0] == math.inf


def test_flat_bhattacharyya_depends_on_the_frame_point_sets_do_not() -> None:
    a, b = spline(seed=1), spline(seed=2)
    t = np.array([25.0, -8.0, 1.5])  # the same pair far from the origin, as in the world frame
    assert metrics.bhattacharyya_flat(a + t, b + t)[0] < 0.5 * metrics.bhattacharyya_flat(a, b)[0]
    np.testing.assert_allclose(
        metrics.bhattacharyya_points(a + t, b + t), metrics.bhattacharyya_points(a, b), rtol=1e-9
    )


def test_bhattacharyya_needs_a_positive_covariance_floor() -> None:
    with pytest.raises(ValueError, match="reg_m2 must be > 0"):
        metrics.bhattacharyya_points(spline(), spline(), 0.0)


def test_metrics_reject_bad_shapes_and_non_finite_points() -> None:
    with pytest.raises(ValueError, match=r"\(N, K, 3\)"):
        metrics.mse(np.zeros((2, 10)), np.zeros((2, 10)))
    bad = spline()
    bad[0, 3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN or Inf"):
        metrics.cosine_similarity(bad, spline())


finite = st.floats(-20, 20, allow_nan=False, width=64)


@settings(max_examples=60, deadline=None)
@given(arrays(np.float64, (2, 6, 3), elements=finite), arrays(np.float64, (2, 6, 3), elements=finite))
def test_bhattacharyya_is_symmetric_and_non_negative(a: np.ndarray, b: np.ndarray) -> None:
    for fn in (metrics.bhattacharyya_points, metrics.bhattacharyya_flat):
        dab = fn(a, b)
        np.testing.assert_allclose(dab, fn(b, a), rtol=1e-9, atol=1e-12)
        assert (dab >= 0).all()


@settings(max_examples=40, deadline=None)
@given(
    arrays(np.float64, (1, 6, 3), elements=finite),
    arrays(np.float64, (1, 6, 3), elements=finite),
    st.floats(-math.pi, math.pi),
    arrays(np.float64, (3,), elements=finite),
)
def test_mse_and_bhattacharyya_are_invariant_under_a_rigid_motion(
    a: np.ndarray, b: np.ndarray, yaw: float, t: np.ndarray
) -> None:
    c, s = math.cos(yaw), math.sin(yaw)
    r = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    ta, tb = a @ r.T + t, b @ r.T + t
    np.testing.assert_allclose(metrics.mse(ta, tb), metrics.mse(a, b), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(
        metrics.bhattacharyya_points(ta, tb), metrics.bhattacharyya_points(a, b), rtol=1e-6, atol=1e-9
    )


def test_mean_ci95_matches_the_t_interval_by_hand() -> None:
    ci = metrics.mean_ci95(np.array([1.0, 2.0, 3.0, 4.0]))
    # sd = sqrt(5/3), t_{0.975, 3} = 3.182446
    assert ci.mean == 2.5
    assert ci.half_width == pytest.approx(3.182446 * math.sqrt(5 / 3) / 2, rel=1e-6)
    assert math.isnan(metrics.mean_ci95(np.array([3.0])).half_width)
    with pytest.raises(ValueError):
        metrics.mean_ci95(np.array([]))


# ------------------------------------------------------------------------------------------------- evaluation
@pytest.fixture(scope="module")
def exported_policy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    torch.manual_seed(0)
    cfg = ModelConfig(input_height=32, input_width=32, state_frame="local", output_frame="local")
    policy = build_policy(cfg, 10, 2.0)
    path = tmp_path_factory.mktemp("policy") / "policy.ts"
    meta = policy_metadata(
        policy, cfg.model_dump(mode="json"), {"dataset": {"train_world_seeds": [1000, 1001]}}
    )
    export_torchscript(policy, path, meta)
    return path


def test_evaluation_writes_per_sample_metrics_summary_and_figures(
    exported_policy: Path, tmp_path: Path
) -> None:
    data = write_synthetic_npz(
        tmp_path / "heldout.npz", num_episodes=2, samples_per_episode=7, first_world_seed=7000
    )
    out = tmp_path / "eval"
    summary = evaluate(exported_policy, [data], out, reg_m2=0.01, batch_size=5)
    assert summary["num_samples"] == 14 and summary["num_episodes"] == 2
    assert summary["held_out"] == {"known": True, "eval_world_seeds": 2, "overlap_with_training": []}
    with open(out / "per_sample.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 14
    mse_world = np.array([float(r["mse_world"]) for r in rows])
    mse_local = np.array([float(r["mse_local"]) for r in rows])
    np.testing.assert_allclose(mse_world, mse_local, rtol=1e-6)  # rigid-motion invariance
    m = json.loads((out / "summary.json").read_text())["metrics"]
    assert m["mse_world"]["mean"] == pytest.approx(mse_world.mean())
    assert m["cosine_local"]["ci95_half_width"] == pytest.approx(
        metrics.mean_ci95(np.array([float(r["cosine_local"]) for r in rows])).half_width
    )
    bp = np.array([float(r["bhattacharyya_points_world"]) for r in rows])
    np.testing.assert_allclose(bp, [float(r["bhattacharyya_points_local"]) for r in rows], rtol=1e-5)
    assert m["bhattacharyya_flat_world"]["mean"] == pytest.approx(
        np.mean([float(r["bhattacharyya_flat_world"]) for r in rows])
    )
    md = (out / "summary.md").read_text()
    assert "| MSE (m^2) | world |" in md and "none used in training" in md and "0.9446" in md
    # The thesis's 0.0254 and its target sit on the flattened form's world row only.
    rows_md = {"/".join(c.strip() for c in r.split("|")[1:3]): r for r in md.splitlines() if "|" in r}
    flat_row = rows_md["Bhattacharyya distance, flattened values (thesis form)/world"]
    assert "0.0254" in flat_row and "< 0.0254" in flat_row
    assert "0.0254" not in rows_md["Bhattacharyya distance, 3-D point sets/world"]
    import matplotlib.image as mpimg

    for frame in ("world", "local"):
        img = mpimg.imread(out / f"bsplines_{frame}.png")
        assert img.shape[0] > 500 and img.std() > 0.01  # drawn, not blank


def test_evaluation_of_several_hypotheses_reports_the_flown_plan_and_the_nearest(tmp_path: Path) -> None:
    torch.manual_seed(0)
    cfg = ModelConfig(
        input_height=32, input_width=32, state_frame="local", output_frame="local", hypotheses=3
    )
    policy = build_policy(cfg, 10, 2.0)
    path = tmp_path / "policy.ts"
    export_torchscript(policy, path, policy_metadata(policy, cfg.model_dump(mode="json")))
    data = write_synthetic_npz(
        tmp_path / "h.npz", num_episodes=2, samples_per_episode=5, first_world_seed=7000
    )
    out = tmp_path / "eval"
    evaluate(path, [data], out)
    with open(out / "per_sample.csv") as f:
        rows = list(csv.DictReader(f))
    flown = np.array([float(r["mse_world"]) for r in rows])
    best = np.array([float(r["mse_best_of_m_world"]) for r in rows])
    assert (best <= flown + 1e-9).all()
    md = (out / "summary.md").read_text()
    assert "The policy has 3 hypotheses" in md
    # A one-plan policy has no such column.
    one = tmp_path / "one.ts"
    cfg1 = cfg.model_copy(update={"hypotheses": 1})
    p1 = build_policy(cfg1, 10, 2.0)
    export_torchscript(p1, one, policy_metadata(p1, cfg1.model_dump(mode="json")))
    assert "mse_best_of_m_world" not in evaluate(one, [data], tmp_path / "eval1")["metrics"]


def test_evaluation_refuses_worlds_seen_in_training(exported_policy: Path, tmp_path: Path) -> None:
    data = write_synthetic_npz(
        tmp_path / "seen.npz", num_episodes=2, samples_per_episode=3, first_world_seed=1000
    )
    with pytest.raises(ValueError, match="used in training"):
        evaluate(exported_policy, [data], tmp_path / "eval")
    summary = evaluate(exported_policy, [data], tmp_path / "eval", allow_seen_worlds=True)
    assert summary["held_out"]["overlap_with_training"] == [1000, 1001]


def test_evaluation_script_reports_a_bad_dataset_path(exported_policy: Path, tmp_path: Path) -> None:
    sys.path.insert(0, str(ROOT / "training_only"))
    try:
        import evaluate_policy
    finally:
        sys.path.pop(0)
    rc = evaluate_policy.main(
        ["--policy", str(exported_policy), "--data", str(tmp_path / "nope.npz"), "--out", str(tmp_path / "o")]
    )
    assert rc == 2
