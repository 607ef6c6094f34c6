"""Each algorithm's callback on scripted streams: who flies, what is recorded, gate switching and
hysteresis."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quad_il.imitation import (
    BCLearner,
    Controller,
    DAggerLearner,
    Decision,
    EILLearner,
    EpisodeOutcome,
    GateParams,
    HGDAggerLearner,
    ImitationError,
    ImitationLearnerBase,
    Observation,
    Pair,
    Partition,
    RoundAlgorithmConfig,
    SplineAction,
    make_learner,
)
from quad_il.imitation.bspline import DeviationParams
from quad_il.imitation.config import DAggerConfig, GateConfig, HGDAggerConfig, MegaDAggerConfig
from quad_il.imitation.gate import GateEvent, HysteresisGate

DT_STEP_S = 0.1
BASE_CTRL = np.column_stack([np.linspace(0.0, 4.0, 8), np.zeros(8), np.ones(8)])


def obs(step: int, episode: int = 0) -> Observation:
    return Observation(
        stamp_s=step * DT_STEP_S,
        frame_seq=step,
        episode_id=episode,
        p_world_body=[0.0, 0.0, 1.0],
        v_world=[0.0, 0.0, 0.0],
        q_world_body=[0.0, 0.0, 0.0, 1.0],
        goal_world=[10.0, 0.0, 1.0],
    )


def plan(step: int, offset_y_m: float = 0.0) -> SplineAction:
    """The expert's plan is the base path; a learner plan offset sideways by d deviates by exactly d."""
    return SplineAction.uniform(BASE_CTRL + [0.0, offset_y_m, 0.0], 0.4, start_time_s=step * DT_STEP_S)


def stream(
    deviations: list[float | None], episode: int = 0, expert_missing: tuple[int, ...] = ()
) -> list[Pair]:
    """One pair per deviation: learner offset by d (None: no learner plan); expert missing on listed steps."""
    pairs = []
    for i, d in enumerate(deviations):
        expert = None if i in expert_missing else plan(i)
        learner = None if d is None else plan(i, d)
        pairs.append(Pair.single(obs(i, episode), expert, learner))
    return pairs


def run(learner: ImitationLearnerBase, pairs: list[Pair], outcome: EpisodeOutcome | None = None):
    learner.start_episode(pairs[0].obs.episode_id)
    decisions = [learner.step(p) for p in pairs]
    tail = learner.end_episode(outcome or EpisodeOutcome(reached_goal=True))
    return decisions, tail


def flyers(decisions: list[Decision]) -> str:
    return "".join(
        {Controller.EXPERT: "E", Controller.LEARNER: "L", Controller.NONE: "-"}[d.controller]
        for d in decisions
    )


GATE = GateParams(on_threshold_m=1.0, off_threshold_m=0.5)
DEV = DeviationParams(metric="sampled_rms", horizon_s=2.0, num_samples=21)


# ---- BC
# ------------------------------------------------------------------------------------------------------------


def test_bc_expert_flies_and_every_expert_plan_is_recorded() -> None:
    decisions, tail = run(
        BCLearner(0, np.random.default_rng(0)), stream([0.0, 3.0, None, 0.2], expert_missing=(2,))
    )
    assert flyers(decisions) == "EE-E"
    recs = [r for d in decisions for r in d.records]
    assert [r.obs.frame_seq for r in recs] == [0, 1, 3]
    assert all(r.partition is Partition.DEMO and r.source == "expert" for r in recs)
    assert recs[1].label.allclose(plan(1))
    assert decisions[1].action is not None and decisions[1].action.allclose(plan(1))
    assert tail == ()


# ---- DAgger
# --------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("beta", "expected"), [(0.0, "LLLLL"), (1.0, "EEEEE")])
def test_dagger_extreme_betas_fly_one_controller_and_label_every_step(beta: float, expected: str) -> None:
    decisions, _ = run(DAggerLearner(3, np.random.default_rng(0), beta), stream([2.0] * 5))
    assert flyers(decisions) == expected
    recs = [r for d in decisions for r in d.records]
    assert len(recs) == 5
    assert all(r.partition is Partition.DEMO and r.label.allclose(plan(r.obs.frame_seq)) for r in recs)
    assert all(r.round_index == 3 for r in recs)


def test_dagger_per_step_mixing_reproduces_the_seeded_coin_flips() -> None:
    beta, n = 0.3, 2000
    decisions, _ = run(DAggerLearner(1, np.random.default_rng(42), beta), stream([0.5] * n))
    reference = np.random.default_rng(42).random(n) < beta
    assert [d.controller is Controller.EXPERT for d in decisions] == reference.tolist()
    frac = np.mean(reference)
    assert abs(frac - beta) < 4 * math.sqrt(beta * (1 - beta) / n)
    # The expert labels every visited state, whoever flew.
    assert sum(len(d.records) for d in decisions) == n


def test_dagger_per_episode_mixing_keeps_one_controller_per_episode() -> None:
    learner = DAggerLearner(1, np.random.default_rng(5), 0.5, mixing="per_episode")
    reference = np.random.default_rng(5).random(40) < 0.5
    for ep in range(40):
        decisions, _ = run(learner, stream([0.5] * 6, episode=ep))
        assert len(set(flyers(decisions))) == 1
        assert (flyers(decisions)[0] == "E") == reference[ep]


def test_dagger_falls_back_to_the_other_plan_and_skips_unlabelled_steps() -> None:
    # beta = 0: learner preferred; step 1 has no learner plan -> expert; step 2 has no expert plan -> no
    # label.
    decisions, _ = run(
        DAggerLearner(1, np.random.default_rng(0), 0.0), stream([0.1, None, 0.1], expert_missing=(2,))
    )
    assert flyers(decisions) == "LEL"
    assert [len(d.records) for d in decisions] == [1, 1, 0]


def test_dagger_round_beta_comes_from_the_schedule() -> None:
    algo = DAggerConfig.model_validate({"beta": {"kind": "exponential", "decay": 0.5}})
    learner = make_learner(
        RoundAlgorithmConfig(algorithm=algo, round_index=3, seed=0), np.random.default_rng(0)
    )
    assert isinstance(learner, DAggerLearner) and learner.beta == pytest.approx(0.125)
    forced = make_learner(
        RoundAlgorithmConfig(algorithm=algo, round_index=3, seed=0, beta=0.9), np.random.default_rng(0)
    )
    assert isinstance(forced, DAggerLearner) and forced.beta == pytest.approx(0.9)


# ---- gate
# ----------------------------------------------------------------------------------------------------------


def test_gate_is_a_schmitt_trigger() -> None:
    gate = HysteresisGate(GATE)
    events = [gate.update(d) for d in [0.2, 1.2, 0.8, 0.6, 0.4, 0.9, 1.0, 1.01, 0.5, 0.49]]
    assert events == [
        GateEvent.NONE,
        GateEvent.ONSET,
        GateEvent.NONE,
        GateEvent.NONE,
        GateEvent.RELEASE,
        GateEvent.NONE,
        GateEvent.NONE,
        GateEvent.ONSET,
        GateEvent.NONE,
        GateEvent.RELEASE,
    ]
    assert gate.onsets == 2
    with pytest.raises(ValueError, match="NaN"):
        gate.update(math.nan)


def test_gate_parameters_are_validated() -> None:
    with pytest.raises(ValueError, match="off_threshold_m must be in"):
        GateParams(on_threshold_m=0.5, off_threshold_m=0.6)
    with pytest.raises(ValueError, match="min_intervention_steps must be >= 1"):
        GateParams(min_intervention_steps=0)
    with pytest.raises(ValueError, match="off_threshold_m .* must be <= on_threshold_m"):
        GateConfig(on_threshold_m=0.5, off_threshold_m=0.6)


# ---- HG-DAgger
# -----------------------------------------------------------------------------------------------------


def test_hg_dagger_gate_switching_with_hysteresis_and_only_expert_steps_recorded() -> None:
    devs = [0.2, 1.2, 0.8, 0.6, 0.4, 0.9, 1.1, 0.3]
    decisions, tail = run(HGDAggerLearner(2, np.random.default_rng(0), GATE, DEV), stream(devs))
    assert flyers(decisions) == "LEEELLEL"
    assert [d.intervening for d in decisions] == [c == "E" for c in "LEEELLEL"]
    for d, dev in zip(decisions, devs, strict=True):
        assert d.deviation_m == pytest.approx(dev, abs=1e-12)
    recs = [r for d in decisions for r in d.records]
    assert [r.obs.frame_seq for r in recs] == [1, 2, 3, 6]
    for r in recs:
        assert (
            r.partition is Partition.INTERVENTION
            and r.source == "expert"
            and r.controller is Controller.EXPERT
        )
        assert r.label.allclose(plan(r.obs.frame_seq))
        assert r.contrast is not None and r.contrast.allclose(plan(r.obs.frame_seq, devs[r.obs.frame_seq]))
    assert tail == ()
    learner_actions = [d.action for d in decisions if d.controller is Controller.LEARNER]
    assert all(a is not None for a in learner_actions)


def test_hg_dagger_minimum_intervention_length() -> None:
    gate = GateParams(on_threshold_m=1.0, off_threshold_m=0.5, min_intervention_steps=3)
    decisions, _ = run(
        HGDAggerLearner(1, np.random.default_rng(0), gate, DEV), stream([1.5, 0.1, 0.1, 0.1, 0.1])
    )
    assert flyers(decisions) == "EEELL"


def test_hg_dagger_missing_learner_plan_hands_control_to_the_expert() -> None:
    decisions, _ = run(HGDAggerLearner(1, np.random.default_rng(0), GATE, DEV), stream([0.1, None, 0.1]))
    assert flyers(decisions) == "LEL"
    assert math.isinf(decisions[1].deviation_m)
    assert len(decisions[1].records) == 1 and decisions[1].records[0].contrast is None


def test_hg_dagger_missing_expert_plan_freezes_the_gate_and_records_nothing() -> None:
    decisions, _ = run(
        HGDAggerLearner(1, np.random.default_rng(0), GATE, DEV),
        stream([1.5, 0.1, 0.1, 1.5], expert_missing=(1, 3)),
    )
    # Step 1: no expert plan during an intervention -> the learner flies, the gate stays open, nothing
    # recorded.
    assert flyers(decisions) == "ELLL"
    assert [d.intervening for d in decisions] == [True, True, False, False]
    assert [len(d.records) for d in decisions] == [1, 0, 0, 0]


def test_learners_count_steps_and_interventions() -> None:
    learner = HGDAggerLearner(1, np.random.default_rng(0), GATE, DEV)
    run(learner, stream([0.2, 1.2, 0.8, 0.6, 0.4, 0.9, 1.1, 0.3]))
    s = learner.stats
    assert (s.steps, s.steps_expert, s.steps_learner, s.interventions) == (8, 4, 4, 2)
    assert s.records["intervention"] == 4


# ---- EIL
# -----------------------------------------------------------------------------------------------------------


def _eil(window: int = 2, record_good: bool = True) -> EILLearner:
    return EILLearner(
        1, np.random.default_rng(0), GATE, DEV, bad_window_steps=window, record_good=record_good
    )


EIL_DEVS = [0.1, 0.1, 0.1, 0.1, 1.5, 1.5, 0.2, 0.1, 0.1, 0.1]


def test_eil_partitions_good_bad_and_intervention_with_delayed_emission() -> None:
    decisions, tail = run(_eil(window=2), stream(EIL_DEVS))
    assert flyers(decisions) == "LLLLEELLLL"
    emitted = [[(r.obs.frame_seq, r.partition.value) for r in d.records] for d in decisions]
    assert emitted == [
        [],
        [],
        [(0, "good")],
        [(1, "good")],
        [(2, "bad"), (3, "bad"), (4, "bad"), (4, "intervention")],
        [(5, "intervention")],
        [],
        [],
        [(6, "good")],
        [(7, "good")],
    ]
    assert [(r.obs.frame_seq, r.partition.value) for r in tail] == [(8, "good"), (9, "good")]
    all_recs = [r for d in decisions for r in d.records] + list(tail)
    for r in all_recs:
        expected = (
            plan(r.obs.frame_seq)
            if r.partition is Partition.INTERVENTION
            else plan(r.obs.frame_seq, EIL_DEVS[r.obs.frame_seq])
        )
        assert r.label.allclose(expected)
        assert r.source == ("expert" if r.partition is Partition.INTERVENTION else "learner")
    # The onset step's learner plan is bad although the expert flew it.
    onset_bad = [r for r in decisions[4].records if r.partition is Partition.BAD and r.obs.frame_seq == 4]
    assert onset_bad[0].controller is Controller.EXPERT


def test_eil_collision_turns_the_pending_learner_steps_bad() -> None:
    _, tail = run(_eil(window=2), stream(EIL_DEVS), EpisodeOutcome(collided=True, collision_time_s=1.0))
    assert [(r.obs.frame_seq, r.partition.value) for r in tail] == [(8, "bad"), (9, "bad")]


def test_eil_without_good_records_and_with_zero_window() -> None:
    decisions, tail = run(_eil(window=2, record_good=False), stream(EIL_DEVS))
    parts = [r.partition.value for d in decisions for r in d.records] + [r.partition.value for r in tail]
    assert parts == ["bad", "bad", "bad", "intervention", "intervention"]
    decisions, tail = run(_eil(window=0), stream(EIL_DEVS))
    parts = [(r.obs.frame_seq, r.partition.value) for d in decisions for r in d.records]
    assert parts[:5] == [(0, "good"), (1, "good"), (2, "good"), (3, "good"), (4, "bad")]
    assert tail == ()


# ---- the base class contract
# ---------------------------------------------------------------------------------------


class _AlwaysLearner(ImitationLearnerBase):
    """A user-defined algorithm: override the callback only (thesis section 3.8)."""

    name = "always_learner"

    def callback(self, pair: Pair) -> Decision:
        if pair.learner is None:
            return Decision(Controller.NONE, None)
        return Decision(Controller.LEARNER, pair.learner)


def test_a_subclass_overriding_only_the_callback_is_a_complete_learner() -> None:
    learner = _AlwaysLearner(0, np.random.default_rng(0))
    decisions, tail = run(learner, stream([0.3, None, 0.3]))
    assert flyers(decisions) == "L-L" and tail == ()
    assert learner.stats.steps_none == 1 and learner.stats.missing_learner == 1


def test_episode_protocol_violations_are_errors() -> None:
    learner = BCLearner(0, np.random.default_rng(0))
    with pytest.raises(ImitationError, match="before start_episode"):
        learner.step(stream([0.0])[0])
    learner.start_episode(0)
    with pytest.raises(ImitationError, match="still open"):
        learner.start_episode(1)
    with pytest.raises(ImitationError, match="pair from episode 4 fed to open episode 0"):
        learner.step(stream([0.0], episode=4)[0])
    learner.end_episode(EpisodeOutcome())
    with pytest.raises(ImitationError, match="without an open episode"):
        learner.end_episode(EpisodeOutcome())


def test_a_callback_that_flies_nothing_with_a_plan_is_rejected() -> None:
    class Broken(ImitationLearnerBase):
        def callback(self, pair: Pair) -> Decision:
            return Decision(Controller.EXPERT, None)

    learner = Broken(0, np.random.default_rng(0))
    learner.start_episode(0)
    with pytest.raises(ImitationError, match="flies Controller.EXPERT with action None"):
        learner.step(stream([0.0])[0])


def test_invalid_observations_are_rejected_with_the_field_name() -> None:
    with pytest.raises(ImitationError, match="p_world_body contains NaN"):
        Observation(0.0, 0, 0, [math.nan, 0, 0], [0, 0, 0], [0, 0, 0, 1], [1, 0, 0])
    with pytest.raises(ImitationError, match="q_world_body must be a unit quaternion"):
        Observation(0.0, 0, 0, [0, 0, 0], [0, 0, 0], [0, 0, 0, 0], [1, 0, 0])
    with pytest.raises(ImitationError, match="goal_world must have 3 elements"):
        Observation(0.0, 0, 0, [0, 0, 0], [0, 0, 0], [0, 0, 0, 1], [1, 0])


def test_make_learner_selects_the_algorithm_and_collects_as_bc_without_a_policy() -> None:
    rng = np.random.default_rng(0)
    hg = HGDAggerConfig()
    assert isinstance(
        make_learner(RoundAlgorithmConfig(algorithm=hg, round_index=1, seed=0), rng), HGDAggerLearner
    )
    first = make_learner(RoundAlgorithmConfig(algorithm=hg, round_index=0, seed=0, expert_only=True), rng)
    assert isinstance(first, BCLearner)
    with pytest.raises(ImitationError, match="mega_dagger needs a clearance map"):
        make_learner(RoundAlgorithmConfig(algorithm=MegaDAggerConfig(), round_index=1, seed=0), rng)
