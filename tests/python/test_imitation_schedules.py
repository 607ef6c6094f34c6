"""DAgger's beta schedules against their closed forms, and the algorithm config's validation messages."""

from __future__ import annotations

import pytest
from pydantic import TypeAdapter, ValidationError

from quad_il.imitation.config import AlgorithmConfig, DAggerConfig
from quad_il.imitation.schedules import BetaSchedule


@pytest.mark.parametrize("i", range(8))
def test_exponential_schedule_is_beta0_times_decay_to_the_round(i: int) -> None:
    s = BetaSchedule(kind="exponential", beta0=0.9, decay=0.6)
    assert s.beta(i) == pytest.approx(0.9 * 0.6**i, rel=1e-15)


def test_linear_schedule_reaches_zero_after_rounds_to_zero() -> None:
    s = BetaSchedule(kind="linear", beta0=1.0, rounds_to_zero=4)
    assert [s.beta(i) for i in range(7)] == pytest.approx([1.0, 0.75, 0.5, 0.25, 0.0, 0.0, 0.0])


def test_floor_and_constant_schedule() -> None:
    assert BetaSchedule(kind="exponential", decay=0.5, beta_min=0.1).beta(10) == pytest.approx(0.1)
    assert BetaSchedule(kind="linear", rounds_to_zero=2, beta_min=0.2).beta(1) == pytest.approx(0.5)
    assert BetaSchedule(kind="constant", beta0=0.4).beta(9) == pytest.approx(0.4)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"beta0": 1.5}, "beta0 must be in \\[0, 1\\], got 1.5"),
        ({"decay": 1.0}, "decay must be in \\(0, 1\\), got 1.0"),
        ({"rounds_to_zero": 0}, "rounds_to_zero must be >= 1, got 0"),
        ({"kind": "cosine"}, "got 'cosine'"),
    ],
)
def test_bad_schedules_are_rejected(kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        BetaSchedule(**kwargs)


def test_negative_round_is_rejected() -> None:
    with pytest.raises(ValueError, match="round_index must be >= 0"):
        BetaSchedule().beta(-1)


def test_algorithm_config_selects_by_name_and_names_the_bad_key() -> None:
    adapter = TypeAdapter(AlgorithmConfig)
    cfg = adapter.validate_python({"name": "dagger", "beta": {"kind": "linear", "rounds_to_zero": 3}})
    assert isinstance(cfg, DAggerConfig) and cfg.beta.schedule().beta(1) == pytest.approx(2 / 3)
    with pytest.raises(ValidationError) as e:
        adapter.validate_python({"name": "dagger", "beta": {"kind": "linear", "rounds_to_zeroo": 3}})
    assert e.value.errors()[0]["loc"] == ("dagger", "beta", "rounds_to_zeroo")
    with pytest.raises(ValidationError) as e:
        adapter.validate_python({"name": "hg_dagger", "gate": {"on_threshold_m": -1.0}})
    assert e.value.errors()[0]["loc"] == ("hg_dagger", "gate", "on_threshold_m")
    with pytest.raises(ValidationError, match="does not match any of the expected tags"):
        adapter.validate_python({"name": "dagga"})
