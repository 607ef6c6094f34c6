"""MEGA-DAgger: clearance/CBF safety filter, label score, conflict resolution, gate expert, collision
window."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quad_il.imitation import (
    Controller,
    EpisodeOutcome,
    ImitationError,
    MegaDAggerLearner,
    Observation,
    Pair,
    Partition,
    PointCloudClearance,
    Record,
    SplineAction,
    check_label_safety,
    label_score,
    resolve_conflicts,
)
from quad_il.imitation.config import MegaConflictConfig, MegaDAggerConfig
from quad_il.imitation.learners import observation_features
from quad_il.imitation.safety import SafetyParams, ScoreParams, WorldClearance

H_S = 2.0
WALL_X_M = 5.0
VOXEL_M = 0.1


def wall() -> PointCloudClearance:
    """Voxel centres on the plane x = 5 (y in [-2, 2], z in [0, 2]), so clearance(x, 0, 1) = 5 - x - 0.05."""
    ys = 0.1 * np.arange(-20, 21)
    zs = 1.0 + 0.1 * np.arange(-10, 11)
    yy, zz = np.meshgrid(ys, zs)
    pts = np.column_stack([np.full(yy.size, WALL_X_M), yy.ravel(), zz.ravel()])
    return PointCloudClearance(pts, VOXEL_M)


def line(x0: float, x1: float, t0: float = 0.0, y: float = 0.0) -> SplineAction:
    """Constant-velocity path from x0 to x1 over [t0, t0 + H] (cubic uniform spline, 8 collinear points)."""
    b = (x1 - x0) / 5.0
    xs = x0 - b + b * np.arange(8)
    return SplineAction.uniform(np.column_stack([xs, np.full(8, y), np.ones(8)]), H_S / 5.0, start_time_s=t0)


def obs(
    step: int, episode: int = 0, features: list[float] | None = None, p=(0.0, 0.0, 1.0), yaw: float = 0.0
):
    return Observation(
        stamp_s=0.1 * step,
        frame_seq=step,
        episode_id=episode,
        p_world_body=p,
        v_world=[0.0, 0.0, 0.0],
        q_world_body=[0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)],
        goal_world=[10.0, 0.0, 1.0],
        features=features,
    )


SAFETY = SafetyParams(min_clearance_m=0.3, cbf_gamma=0.5, horizon_s=H_S, num_samples=21)


def test_line_helper_is_a_constant_velocity_path() -> None:
    a = line(0.0, 4.0, t0=3.0)
    np.testing.assert_allclose(a.positions([3.0, 4.0, 5.0])[:, 0], [0.0, 2.0, 4.0], atol=1e-12)


def test_point_cloud_clearance_is_distance_to_the_voxel_surface() -> None:
    c = wall().clearance_m(np.array([[0.0, 0.0, 1.0], [4.0, 0.3, 1.2], [5.0, 0.0, 1.0]]))
    np.testing.assert_allclose(c, [4.95, 0.95, 0.0], atol=1e-9)
    assert np.isinf(PointCloudClearance(np.zeros((0, 3)), 0.1).clearance_m(np.zeros((2, 3)))).all()


def test_world_clearance_knows_nothing_before_a_map_and_follows_the_latest_world() -> None:
    c = WorldClearance()
    p = np.array([[0.0, 0.0, 1.0], [4.0, 0.3, 1.2]])
    np.testing.assert_array_equal(c.clearance_m(p), [0.0, 0.0])  # no map yet: nothing counts as safe
    assert c.queries_without_map == 1
    c.update(wall())
    np.testing.assert_allclose(c.clearance_m(p), [4.95, 0.95], atol=1e-9)
    c.update(PointCloudClearance(np.array([[0.0, 0.0, 2.0]]), VOXEL_M))  # the next world replaces the wall
    np.testing.assert_allclose(c.clearance_m(p[:1]), [0.95], atol=1e-9)
    assert (c.updates, c.queries_without_map) == (2, 1)
    learner = MegaDAggerLearner(0, np.random.default_rng(0), MegaDAggerConfig(experts=["a", "b"]), c)
    assert learner.clearance is c


def test_a_label_into_the_wall_is_unsafe_by_clearance() -> None:
    res = check_label_safety(line(0.0, 6.0), 0.0, wall(), SAFETY)
    assert not res.safe
    assert "clearance 0.150 m < 0.300 m at t_obs + 1.60 s" in res.reason


def test_cbf_condition_rejects_a_fast_approach_that_keeps_its_clearance() -> None:
    # h_k = 4.65 - 0.2 k (k = 0..20) stays >= 0.65; h_{k+1} >= (1 - g) h_k  <=>  g h_k >= 0.2.
    ok = check_label_safety(line(0.0, 4.0), 0.0, wall(), SAFETY)
    assert ok.safe and ok.reason == "" and ok.min_clearance_m == pytest.approx(0.95)
    strict = SafetyParams(min_clearance_m=0.3, cbf_gamma=0.2, horizon_s=H_S, num_samples=21)
    res = check_label_safety(line(0.0, 4.0), 0.0, wall(), strict)
    assert not res.safe
    assert (
        "CBF condition" in res.reason and "t_obs + 2.00 s" in res.reason
    )  # first violation: h_19 = 0.85 < 1


def test_a_label_parallel_to_the_wall_is_safe_with_its_clearance() -> None:
    ctrl = np.column_stack([np.full(8, 3.0), np.linspace(-1.4, 1.4, 8), np.ones(8)])
    res = check_label_safety(SplineAction.uniform(ctrl, 0.4), 0.0, wall(), SAFETY)
    assert res.safe and res.min_clearance_m == pytest.approx(1.95, abs=1e-9)


def test_score_weighs_clearance_and_progress_towards_the_goal() -> None:
    params = ScoreParams(safety_weight=0.5, progress_weight=0.5, clearance_cap_m=2.0, max_speed_mps=2.0)
    o = obs(0)
    # 0 -> 2 m towards a goal 10 m away: progress (10 - 8) / (2 m/s * 2 s) = 0.5; clearance 2.95 m capped ->
    # 1.
    assert label_score(line(0.0, 2.0), o, 2.95, H_S, params) == pytest.approx(0.75)
    # Backwards: progress -0.5.
    assert label_score(line(0.0, -2.0), o, 4.95, H_S, params) == pytest.approx(0.25)
    # Half the cap of clearance, no progress.
    assert label_score(line(0.0, 0.0), o, 1.0, H_S, params) == pytest.approx(0.25)


def _mega(gate_expert: str = "round_robin", seed: int = 0, **kw) -> MegaDAggerLearner:
    cfg = MegaDAggerConfig.model_validate(
        {
            "experts": ["a", "b"],
            "gate_expert": gate_expert,
            "gate": {"on_threshold_m": 1.0, "off_threshold_m": 0.5},
            "safety": {"min_clearance_m": 0.3, "cbf_gamma": 0.5, "horizon_s": H_S, "num_samples": 21},
            **kw,
        }
    )
    return MegaDAggerLearner(1, np.random.default_rng(seed), cfg, wall())


def _pair(step: int, a: SplineAction | None, b: SplineAction | None, learner: SplineAction | None, episode=0):
    return Pair(obs=obs(step, episode), learner=learner, experts={"a": a, "b": b}, primary_expert="a")


def test_unsafe_expert_labels_are_filtered_and_the_safe_one_flies_and_is_recorded() -> None:
    m = _mega()
    m.start_episode(0)
    t = 0.0
    a, b = line(0.0, 6.0, t), line(0.0, 2.0, t)  # a dives into the wall
    d = m.step(_pair(0, a, b, line(0.0, 6.0, t, y=1.5)))  # gate expert a; learner 1.5 m off a
    assert d.controller is Controller.EXPERT and d.expert_name == "b" and d.action is b
    assert d.records == ()  # released at the end of the episode
    assert m.stats.dropped_unsafe == 1
    tail = m.end_episode(EpisodeOutcome(reached_goal=True))
    assert len(tail) == 1
    rec = tail[0]
    assert rec.partition is Partition.INTERVENTION and rec.source == "b" and rec.label is b
    assert rec.score == pytest.approx(0.75) and rec.min_clearance_m == pytest.approx(2.95)


def test_best_score_wins_among_safe_labels_of_the_same_frame() -> None:
    m = _mega()
    m.start_episode(0)
    a, b = line(0.0, 2.0), line(0.0, 1.0)  # progress 0.5 vs 0.25
    d = m.step(_pair(0, a, b, line(0.0, 2.0, y=1.5)))
    assert d.expert_name == "a"
    (rec,) = m.end_episode(EpisodeOutcome())
    assert rec.source == "a" and rec.score == pytest.approx(0.75)


def test_no_safe_label_flies_the_gate_expert_and_records_nothing() -> None:
    m = _mega()
    m.start_episode(0)
    a, b = line(0.0, 6.0), line(0.0, 7.0)
    d = m.step(_pair(0, a, b, line(0.0, 6.0, y=2.0)))
    assert d.controller is Controller.EXPERT and d.expert_name == "a" and d.action is a
    assert m.end_episode(EpisodeOutcome()) == () and m.stats.dropped_unsafe == 2


def test_gate_expert_rotates_round_robin_over_episodes() -> None:
    m = _mega()
    a, b = line(0.0, 2.0), line(0.0, 2.0, y=2.0)
    learner = line(0.0, 2.0)  # identical to a, 2 m from b
    flown = []
    for ep in range(4):
        m.start_episode(ep)
        flown.append(m.step(_pair(0, a, b, learner, episode=ep)).controller)
        m.end_episode(EpisodeOutcome())
    assert flown == [Controller.LEARNER, Controller.EXPERT, Controller.LEARNER, Controller.EXPERT]


def test_random_gate_expert_follows_the_seeded_generator() -> None:
    m = _mega(gate_expert="random", seed=11)
    ref = np.random.default_rng(11)
    for ep in range(10):
        m.start_episode(ep)
        assert m.gate_expert == ["a", "b"][int(ref.integers(2))]
        m.end_episode(EpisodeOutcome())


def test_records_before_a_collision_are_dropped_within_the_window() -> None:
    m = _mega(collision_window_s=0.35)
    m.start_episode(0)
    for i in range(11):
        t = 0.1 * i
        m.step(_pair(i, line(0.0, 2.0, t), line(0.0, 1.0, t), line(0.0, 2.0, t, y=1.5)))
    kept = m.end_episode(EpisodeOutcome(collided=True, collision_time_s=1.0))
    assert [r.obs.frame_seq for r in kept] == [0, 1, 2, 3, 4, 5, 6]
    assert m.stats.dropped_collision == 4


def test_pairs_lacking_a_configured_expert_are_rejected() -> None:
    m = _mega()
    m.start_episode(0)
    with pytest.raises(ImitationError, match=r"lacks the configured experts \['b'\]"):
        m.step(Pair(obs=obs(0), learner=None, experts={"a": line(0, 1)}, primary_expert="a"))


# ---- conflict resolution
# ------------------------------------------------------------------------------------------


def _rec(
    step: int, features, label: SplineAction, score: float, p=(0.0, 0.0, 1.0), yaw: float = 0.0
) -> Record:
    return Record(
        obs=obs(step, features=features, p=p, yaw=yaw),
        label=label,
        partition=Partition.INTERVENTION,
        source="a",
        controller=Controller.EXPERT,
        round_index=1,
        score=score,
    )


CONFLICT = MegaConflictConfig(cosine_threshold=0.99, label_distance_m=0.5, horizon_s=H_S, num_samples=11)


def test_conflicting_labels_of_near_identical_observations_keep_the_higher_score() -> None:
    f = [1.0, 0.0, 0.2]
    near = [1.0, 0.01, 0.2]  # cosine 0.99995
    r_low = _rec(0, near, line(0.1, 2.0, 0.0, y=2.0), 0.4)  # 2 m to the side: conflicts with r_best
    r_best = _rec(1, f, line(0.1, 2.0, 0.1), 0.9)
    r_agree = _rec(2, near, line(0.1, 2.0, 0.2, y=0.1), 0.2)  # 0.1 m away: same decision, no conflict
    r_other = _rec(3, [0.0, 1.0, 0.0], line(0.1, 2.0, 0.3, y=-3.0), 0.1)  # different observation
    r_nan = _rec(4, f, line(0.1, 2.0, 0.4, y=-2.0), math.nan)  # unknown score loses
    res = resolve_conflicts([r_low, r_best, r_agree, r_other, r_nan], CONFLICT)
    assert res.kept == (r_best, r_agree, r_other)
    assert res.dropped == (r_low, r_nan)


def test_labels_are_compared_in_each_observations_own_frame() -> None:
    # The same manoeuvre seen from another place and heading is the same decision, not a conflict.
    f = [0.3, 0.4, 0.5]
    r1 = _rec(0, f, line(0.0, 2.0, 0.0), 0.9)
    ctrl = r1.label.ctrl_pts_world - [0.0, 0.0, 1.0]
    rotated = np.column_stack([-ctrl[:, 1], ctrl[:, 0], ctrl[:, 2]]) + [10.0, 5.0, 1.0]  # yaw +90 deg
    r2 = _rec(
        1, f, SplineAction.uniform(rotated, 0.4, start_time_s=0.1), 0.1, p=(10.0, 5.0, 1.0), yaw=math.pi / 2
    )
    assert resolve_conflicts([r1, r2], CONFLICT).kept == (r1, r2)


def test_default_features_ignore_position_and_heading() -> None:
    depth = np.random.default_rng(0).uniform(0.5, 9.0, size=(24, 32)).astype(np.float32)
    base = Observation(0.0, 0, 0, [0, 0, 1], [1.0, 0.5, 0], [0, 0, 0, 1], [10, 2, 1], depth_m=depth)
    c, s = math.cos(0.7), math.sin(0.7)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    p = np.array([3.0, -4.0, 1.0])
    moved = Observation(
        0.0,
        0,
        0,
        p,
        rot @ [1.0, 0.5, 0],
        [0, 0, math.sin(0.35), math.cos(0.35)],
        p + rot @ [10, 2, 0],
        depth_m=depth,
    )
    f0, f1 = observation_features(base), observation_features(moved)
    assert f0.shape == (3 + 1 + 3 + 48,)
    np.testing.assert_allclose(f0, f1, atol=1e-12)


def test_features_of_different_sizes_are_an_error() -> None:
    with pytest.raises(ImitationError, match="record 1 has 2 observation features, record 0 has 3"):
        resolve_conflicts([_rec(0, [1, 0, 0], line(0, 1), 1.0), _rec(1, [1, 0], line(0, 1), 1.0)], CONFLICT)
