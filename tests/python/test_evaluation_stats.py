"""quad_il.evaluation.stats against published and hand-computed values."""

from __future__ import annotations

import math

import pytest

from quad_il.evaluation.stats import format_rate, mcnemar_exact_p, wilson_interval


@pytest.mark.parametrize(
    ("k", "n", "lo", "hi"),
    [
        # Newcombe (1998), "Two-sided confidence intervals for the single proportion", Table I, method 3.
        (81, 263, 0.2553, 0.3662),
        (15, 148, 0.0624, 0.1605),
        (0, 20, 0.0, 0.1611),
        (1, 29, 0.0061, 0.1718),
        # By hand: p = 0.2, z^2 = 3.8416; centre = (0.2 + 0.19208) / 1.38416 = 0.28327,
        # half = 1.96 / 1.38416 * sqrt(0.016 + 0.0096040) = 0.22664.
        (2, 10, 0.0567, 0.5098),
        (10, 10, 0.7225, 1.0),
    ],
)
def test_wilson_interval_matches_published_values(k: int, n: int, lo: float, hi: float) -> None:
    got = wilson_interval(k, n)
    assert got == pytest.approx((lo, hi), abs=1e-4)


def test_wilson_interval_of_no_episodes_is_nan_and_bad_counts_are_named() -> None:
    assert all(math.isnan(x) for x in wilson_interval(0, 0))
    with pytest.raises(ValueError, match="successes=5, n=4"):
        wilson_interval(5, 4)
    with pytest.raises(ValueError, match="successes=-1"):
        wilson_interval(-1, 4)


def test_mcnemar_exact_p_equals_the_binomial_tails() -> None:
    assert mcnemar_exact_p(0, 0) == 1.0
    assert mcnemar_exact_p(0, 6) == pytest.approx(2 / 64)  # 2 * C(6,0) / 2^6
    assert mcnemar_exact_p(5, 1) == pytest.approx(2 * (1 + 6) / 64)
    assert mcnemar_exact_p(1, 5) == pytest.approx(2 * (1 + 6) / 64)  # symmetric
    assert mcnemar_exact_p(3, 3) == 1.0  # capped at 1
    # 7 gained, 1 lost (the keeping-the-plan comparison's discordant pairs): 2 * (1 + 8) / 256.
    assert mcnemar_exact_p(7, 1) == pytest.approx(18 / 256)
    with pytest.raises(ValueError, match="gained=-1"):
        mcnemar_exact_p(-1, 2)


def test_format_rate_shows_the_interval_in_percent() -> None:
    assert format_rate(2, 10) == "20 % [6-51]"
    assert format_rate(0, 0) == "-"
