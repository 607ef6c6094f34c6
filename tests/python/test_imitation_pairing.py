"""Pairing observations with the plans made from them, by the depth frame's stamp."""

from __future__ import annotations

import numpy as np
import pytest

from quad_il.imitation import ImitationError, Observation, SplineAction
from quad_il.imitation.pairing import StampPairer, stamp_key


def obs(stamp_s: float) -> Observation:
    return Observation(stamp_s, int(stamp_s * 30), 0, [0, 0, 1], [0, 0, 0], [0, 0, 0, 1], [5, 0, 1])


def act(stamp_s: float) -> SplineAction:
    return SplineAction.uniform(np.zeros((5, 3)) + stamp_s, 0.2, start_time_s=stamp_s)


def test_a_frame_is_paired_once_all_sources_arrived_in_any_order() -> None:
    p = StampPairer(["expert", "learner"])
    t = 1.0 / 30.0
    assert p.add_action("learner", t, act(t)) == []
    assert p.add_observation(obs(t)) == []
    (frame,) = p.add_action("expert", t, act(t))
    assert frame.obs.stamp_s == t and set(frame.actions) == {"expert", "learner"}
    assert frame.actions["expert"] is not None and frame.actions["expert"].start_time_s == t
    assert p.pending == 0 and p.stats.paired == 1


def test_stamps_equal_to_the_nanosecond_pair_even_through_float_noise() -> None:
    assert stamp_key(0.1 + 0.2) == stamp_key(0.3)
    p = StampPairer(["expert"])
    p.add_observation(obs(0.3))
    assert len(p.add_action("expert", 0.1 + 0.2, None)) == 1


def test_a_missing_plan_is_completed_with_none_when_a_newer_frame_pairs() -> None:
    p = StampPairer(["expert", "learner"])
    p.add_observation(obs(1.0))
    p.add_action("learner", 1.0, act(1.0))  # the expert could not plan on frame 1.0
    p.add_observation(obs(2.0))
    p.add_action("expert", 2.0, act(2.0))
    out = p.add_action("learner", 2.0, act(2.0))
    assert [f.obs.stamp_s for f in out] == [1.0, 2.0]
    assert out[0].actions["expert"] is None and out[0].actions["learner"] is not None
    assert p.stats.completed_with_missing == 1


def test_the_pending_buffer_is_bounded_and_evictions_are_counted() -> None:
    p = StampPairer(["expert"], max_pending=3)
    for i in range(5):
        p.add_observation(obs(float(i)))
    assert p.pending == 3 and p.stats.evicted == 2


def test_unknown_sources_and_bad_settings_are_errors() -> None:
    with pytest.raises(ImitationError, match="unknown source 'planner'"):
        StampPairer(["expert"]).add_action("planner", 0.0, None)
    with pytest.raises(ImitationError, match="unique and non-empty"):
        StampPairer(["a", "a"])
    with pytest.raises(ImitationError, match="max_pending must be >= 1"):
        StampPairer(["a"], max_pending=0)
