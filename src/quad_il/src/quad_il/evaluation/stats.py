"""Statistics of closed-loop results, from scipy.stats (issue 30): the Wilson 95 % interval of a rate and the
exact McNemar test of a paired comparison. With 20-40 episodes a rate is known only to +-15-20 points; every
rate the project reports carries its interval."""

from __future__ import annotations

import math

from scipy.stats import binomtest

CONFIDENCE = 0.95


def wilson_interval(successes: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The Wilson score interval of successes / n (scipy's binomtest(...).proportion_ci(method="wilson"));
    (nan, nan) for n = 0."""
    if n < 0 or successes < 0 or successes > n:
        raise ValueError(f"wilson_interval: need 0 <= successes <= n, got successes={successes}, n={n}")
    if n == 0:
        return math.nan, math.nan
    ci = binomtest(successes, n).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)


def mcnemar_exact_p(gained: int, lost: int) -> float:
    """Exact two-sided McNemar p-value of a paired comparison from its discordant pairs (goals gained in B
    only, lost in B only): the two-sided binomial test of `gained` in gained + lost trials at p = 1/2. 1 when
    there is no discordant pair."""
    if gained < 0 or lost < 0:
        raise ValueError(f"mcnemar_exact_p: counts must be >= 0, got gained={gained}, lost={lost}")
    n = gained + lost
    if n == 0:
        return 1.0
    return float(binomtest(gained, n, 0.5, alternative="two-sided").pvalue)


def format_rate(successes: int, n: int) -> str:
    """'82 % [67-91]': the rate and its 95 % Wilson interval in percent; '-' for no episodes."""
    if n == 0:
        return "-"
    lo, hi = wilson_interval(successes, n)
    return f"{100 * successes / n:.0f} % [{100 * lo:.0f}-{100 * hi:.0f}]"
