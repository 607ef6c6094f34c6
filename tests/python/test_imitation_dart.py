"""DART's perturbation events (quad_il.imitation.learners.DARTLearner): when they start, what is executed
during them, what is recorded, determinism, and the config's error messages."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from quad_il.imitation import (
    Controller,
    EpisodeOutcome,
    Observation,
    Pair,
    Partition,
    RoundAlgorithmConfig,
    SplineAction,
    make_learner,
)
from quad_il.imitation.config import DARTConfig, DARTRangeConfig
from quad_il.imitation.learners import DARTLearner, turned_about_start

DT_STEP_S = 1.0 / 30.0
BASE_CTRL = np.column_stack([np.linspace(0.0, 6.0, 8), np.zeros(8), np.ones(8)])


def obs(
    step: int, p=(0.0, 0.0, 1.0), v=(3.0, 0.0, 0.0), goal=(30.0, 0.0, 1.0), episode: int = 0
) -> Observation:
    return Observation(
        stamp_s=100.0 + step * DT_STEP_S,
        frame_seq=step,
        episode_id=episode,
        p_world_body=list(p),
        v_world=list(v),
        q_world_body=[0.0, 0.0, 0.0, 1.0],
        goal_world=list(goal),
    )


def plan(step: int) -> SplineAction:
    """The expert's plan on every step: the same trajectory (started at t = 100 s), as a consistent expert
    replanning along its own path gives."""
    del step
    return SplineAction.uniform(BASE_CTRL, 0.4, start_time_s=100.0)


def fly(
    learner: DARTLearner,
    steps: int,
    episode: int = 0,
    expert_missing: tuple[int, ...] = (),
    outcome: EpisodeOutcome | None = None,
    expert=None,
    **obs_kw,
):
    """[(event after the step, decision)] of each step; the records released at the end in `fly.records`."""
    learner.start_episode(episode)
    out = []
    make = expert or plan
    for i in range(steps):
        pair = Pair.single(obs(i, episode=episode, **obs_kw), None if i in expert_missing else make(i), None)
        d = learner.step(pair)
        assert d.records == ()  # DART releases its records at the episode's end
        out.append((learner.event, d))
    fly.records = learner.end_episode(outcome or EpisodeOutcome(reached_goal=True))
    return out


def cfg(**kw) -> DARTConfig:
    """execute_every_steps 1 (a plan executed on every step) unless given."""
    return DARTConfig(**{"execute_every_steps": 1, **kw})


def test_no_event_before_first_after_s_and_events_of_both_kinds_later():
    learner = DARTLearner(0, np.random.default_rng(1), cfg(event_rate_per_s=2.0, first_after_s=1.0))
    steps = fly(learner, 30 * 20)
    first = next(i for i, (ev, _) in enumerate(steps) if ev is not None)
    assert first * DT_STEP_S >= 1.0 - 1e-9
    assert learner.event_counts["brake"] > 0 and learner.event_counts["veer"] > 0


def test_events_keep_min_gap_and_last_their_drawn_duration():
    c = cfg(
        event_rate_per_s=50.0,  # an onset as soon as allowed
        min_gap_s=0.5,
        first_after_s=0.0,
        brake_probability=1.0,
        brake_duration_s=DARTRangeConfig(low=1.0, high=1.0),
    )
    steps = fly(DARTLearner(0, np.random.default_rng(2), c), 30 * 6)
    runs = []  # (start step, length) of each event
    for i, (ev, _) in enumerate(steps):
        if ev is not None and (i == 0 or steps[i - 1][0] is None):
            runs.append([i, 0])
        if ev is not None:
            runs[-1][1] += 1
    assert len(runs) >= 3
    for (s0, n0), (s1, _) in zip(runs, runs[1:], strict=False):
        assert n0 * DT_STEP_S == pytest.approx(1.0, abs=DT_STEP_S + 1e-9)
        assert (s1 - (s0 + n0)) * DT_STEP_S >= 0.5 - DT_STEP_S - 1e-9


def test_no_onset_near_the_goal():
    c = cfg(event_rate_per_s=50.0, first_after_s=0.0, min_goal_distance_m=2.0)
    steps = fly(DARTLearner(0, np.random.default_rng(3), c), 300, goal=(1.5, 0.0, 1.0))
    assert all(ev is None for ev, _ in steps)


def test_brake_executes_a_stop_along_the_line_of_motion_and_records_the_expert_label():
    c = cfg(event_rate_per_s=50.0, first_after_s=0.0, brake_probability=1.0, brake_decel_mps2=3.0)
    steps = fly(DARTLearner(0, np.random.default_rng(4), c), 60)
    braking = [d for ev, d in steps if ev == "brake"]
    assert braking
    d = braking[0]
    assert d.controller is Controller.EXPERT
    a = d.action
    # Starts at the vehicle with its velocity, ends at rest 3 m/s * T / 3 ahead, T = 2 * 3 / 3 = 2 s.
    t0 = a.start_time_s
    p = a.positions([t0, t0 + a.duration_s, t0 + a.duration_s + 1.0])
    np.testing.assert_allclose(p[0], [0.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(p[1], [2.0, 0.0, 1.0], atol=1e-9)
    np.testing.assert_allclose(p[2], p[1], atol=1e-12)
    assert a.duration_s == pytest.approx(2.0)
    # Labels are always the expert's own plan, never the executed stop.
    assert fly.records
    for r in fly.records:
        assert r.partition is Partition.DEMO and r.controller is Controller.EXPERT
        np.testing.assert_array_equal(r.label.ctrl_pts_world, BASE_CTRL)


def test_veer_turns_the_expert_plan_about_its_start_point():
    c = cfg(
        event_rate_per_s=50.0,
        first_after_s=0.0,
        brake_probability=0.0,
        veer_angle_deg=DARTRangeConfig(low=30.0, high=30.0),
    )
    steps = fly(DARTLearner(0, np.random.default_rng(5), c), 60)
    veering = [d for ev, d in steps if ev == "veer"]
    assert veering
    a = veering[0].action
    expert = plan(0)
    p0 = expert.positions([expert.start_time_s])[0]
    np.testing.assert_allclose(a.positions([a.start_time_s])[0], p0, atol=1e-9)
    # The end point is turned by +-30 deg about p0.
    end_e = expert.ctrl_pts_world[-1] - p0
    end_a = a.ctrl_pts_world[-1] - p0
    angle = math.degrees(math.atan2(end_a[1], end_a[0]) - math.atan2(end_e[1], end_e[0]))
    assert abs(angle) == pytest.approx(30.0, abs=1e-9)
    assert np.linalg.norm(end_a) == pytest.approx(np.linalg.norm(end_e))


def test_turned_about_start_keeps_timing_and_height():
    a = plan(3)
    t = turned_about_start(a, math.radians(90.0))
    np.testing.assert_array_equal(t.knots, a.knots)
    assert t.start_time_s == a.start_time_s
    np.testing.assert_allclose(t.ctrl_pts_world[:, 2], a.ctrl_pts_world[:, 2])


def test_records_every_nth_expert_step_and_none_without_expert_plan():
    c = cfg(event_rate_per_s=0.001, record_every_steps=3)  # practically no event, a plan every step
    missing = (4, 5)
    steps = fly(DARTLearner(0, np.random.default_rng(6), c), 30, expert_missing=missing)
    recorded = [r.obs.frame_seq for r in fly.records]
    with_expert = [i for i in range(30) if i not in missing]
    assert recorded == with_expert[::3]
    for i in missing:
        assert steps[i][1].controller is Controller.NONE and steps[i][1].action is None
    for i in with_expert:
        assert steps[i][1].action is not None and steps[i][1].controller is Controller.EXPERT


def test_brake_flies_even_without_an_expert_plan():
    c = cfg(event_rate_per_s=50.0, first_after_s=0.0, brake_probability=1.0)
    steps = fly(DARTLearner(0, np.random.default_rng(7), c), 20, expert_missing=tuple(range(20)))
    assert any(ev == "brake" and d.action is not None for ev, d in steps)


def test_same_seed_same_events_and_a_new_episode_starts_clean():
    c = cfg(event_rate_per_s=1.0)
    a = fly(DARTLearner(0, np.random.default_rng(8), c), 30 * 15)
    b = fly(DARTLearner(0, np.random.default_rng(8), c), 30 * 15)
    assert [ev for ev, _ in a] == [ev for ev, _ in b]
    learner = DARTLearner(0, np.random.default_rng(9), cfg(event_rate_per_s=50.0, first_after_s=0.5))
    fly(learner, 60, episode=0)
    second = fly(learner, 10, episode=1)  # first_after_s counts from the new episode's first step
    assert all(ev is None for ev, _ in second)


def test_make_learner_builds_dart_without_a_learner_policy():
    rc = RoundAlgorithmConfig(algorithm=DARTConfig(), round_index=0, seed=0, expert_only=True)
    assert isinstance(make_learner(rc, np.random.default_rng(0)), DARTLearner)
    rc = RoundAlgorithmConfig.model_validate(
        {"algorithm": {"name": "dart", "event_rate_per_s": 0.2}, "round_index": 1, "seed": 3}
    )
    assert rc.algorithm.event_rate_per_s == 0.2


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"event_rate_per_s": 0.0}, "event_rate_per_s"),
        ({"brake_probability": 1.5}, "brake_probability"),
        ({"record_every_steps": 0}, "record_every_steps"),
        ({"veer_angle_deg": {"low": 10.0, "high": 200.0}}, "veer_angle_deg.high must be <= 180"),
        ({"brake_duration_s": {"low": 2.0, "high": 1.0}}, "high (1.0) must be >= low (2.0)"),
        ({"brake_decel": 3.0}, "brake_decel"),
    ],
)
def test_config_errors_name_the_key(kw, message):
    with pytest.raises(ValidationError, match=message.replace("(", r"\(").replace(")", r"\)")):
        DARTConfig.model_validate(kw)


def test_event_counts_are_reported_for_the_manifest():
    learner = DARTLearner(0, np.random.default_rng(10), cfg(event_rate_per_s=2.0))
    fly(learner, 30 * 10)
    stats = learner.algorithm_stats()
    assert stats == {"events": learner.event_counts}
    assert sum(stats["events"].values()) > 0


def test_plans_are_executed_every_nth_step_and_at_event_onsets():
    c = cfg(
        execute_every_steps=10,
        event_rate_per_s=1.0,
        first_after_s=0.0,
        min_gap_s=0.5,
        brake_duration_s=DARTRangeConfig(low=0.4, high=0.4),
        veer_duration_s=DARTRangeConfig(low=0.4, high=0.4),
    )
    steps = fly(DARTLearner(0, np.random.default_rng(11), c), 30 * 20, expert_missing=(30, 31))
    sent = [i for i, (_, d) in enumerate(steps) if d.action is not None]
    assert sent[0] == 0
    events = [ev for ev, _ in steps]
    changes = {i for i in range(1, len(events)) if events[i] != events[i - 1]}
    assert changes, "no event in 20 s"
    for i in changes:  # every onset and every end sends a plan at once
        assert i in sent, i
    gaps = np.diff(sent)
    assert gaps.max() <= 10 + 2  # the cadence, plus the two steps without an expert plan
    assert 30 not in sent and 31 not in sent
    # without events, exactly every 10th step
    quiet = fly(
        DARTLearner(0, np.random.default_rng(12), cfg(execute_every_steps=10, event_rate_per_s=1e-6)), 45
    )
    assert [i for i, (_, d) in enumerate(quiet) if d.action is not None] == [0, 10, 20, 30, 40]
    assert all(d.controller is Controller.NONE for _, d in quiet if d.action is None)


def test_a_collision_drops_the_records_of_its_last_window():
    c = cfg(event_rate_per_s=0.001, record_every_steps=1, collision_window_s=0.5)
    crash = EpisodeOutcome(collided=True, collision_time_s=100.0 + 29 * DT_STEP_S)
    learner = DARTLearner(0, np.random.default_rng(13), c)
    fly(learner, 30, outcome=crash)
    kept = [r.obs.stamp_s for r in fly.records]
    assert kept and max(kept) < crash.collision_time_s - 0.5
    assert len(kept) + learner.stats.dropped_collision == 30
    assert learner.stats.dropped_collision == 16  # steps 14..29: stamped at or after the crash - 0.5 s


def test_a_departing_expert_plan_is_executed_at_once():
    c = cfg(execute_every_steps=10, event_rate_per_s=1e-6, replan_deviation_m=0.3)

    def expert(i: int) -> SplineAction:  # from step 4 on the expert swerves 1 m to the side
        ctrl = BASE_CTRL + ([0.0, 1.0, 0.0] if i >= 4 else [0.0, 0.0, 0.0])
        return SplineAction.uniform(ctrl, 0.4, start_time_s=100.0)

    steps = fly(DARTLearner(0, np.random.default_rng(14), c), 25, expert=expert)
    assert [i for i, (_, d) in enumerate(steps) if d.action is not None] == [0, 4, 14, 24]
    off = fly(
        DARTLearner(
            0,
            np.random.default_rng(14),
            cfg(execute_every_steps=10, event_rate_per_s=1e-6, replan_deviation_m=0.0),
        ),
        25,
        expert=expert,
    )
    assert [i for i, (_, d) in enumerate(off) if d.action is not None] == [0, 10, 20]
