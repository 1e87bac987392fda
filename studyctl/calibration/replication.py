"""How often a same-size replication of a paper passes each agreement check (pure computation).

A simulated study that reproduces a paper's people exactly still draws its own sample, so a verdict near the
significance level flips from one replication to the next: a published p of 0.07 is reproduced as "not
significant" barely more than half the time. The agreement table states this per verdict beside whether the
simulation reproduced it, and the index the expected count, so a missed verdict can be read against what chance
alone allows.

The published p is read as the two-sided normal deviate z = Φ⁻¹(1 − p/2). Not knowing the true effect (a flat
prior on it), a replication of the same size draws its deviate around z with SD √2 (Cumming 2008, "Replication and
p intervals", Perspect. Psychol. Sci. 3:286; the calibration distance uses the same SD for p-value targets). So a
replication is significant at alpha with probability Φ((z − z_α)/√2) + Φ((−z − z_α)/√2), z_α = Φ⁻¹(1 − α/2); where
the paper states a direction, only the first term (significant the paper's way) reproduces it. Tests whose
statistic is not normal (F, H, U, W) are read through their p, an approximation that keeps the replication's
evidence on the same scale.

A value checked against a band drawn from the paper's own sampling error (its CI or SE, or one recomputed from
its counts or n) is missed the same way: with the true value unknown, a replication's estimate lies around the
published one with variance 2·SE², so it lands in a ±1.96 SE band only P(|Z| < 1.96/√2) = 83 % of the time
(:func:`band_replication`; normal, so approximate for a count or a proportion near 0 or 1). A spread judged by
its ratio within a factor (an SD of n people) has a log-ratio of variance 2/(2(n − 1)) (:func:`spread_replication`).
A CHOSEN band is a tolerance, not a sampling interval: it has no such chance.
"""

from __future__ import annotations

import math

from studyctl.errors import StatsInputError

REPLICATION_SD = math.sqrt(2.0)


def verdict_replication(p: float, alpha: float, *, significant: bool, directed: bool = False) -> float:
    """Probability that a replication of the same size gives the published verdict: significant at ``alpha``
    (the paper's way when ``directed``) if ``significant``, else not significant."""
    if not 0 < p <= 1 or not 0 < alpha < 1:
        raise StatsInputError(f"p {p!r} must lie in (0, 1] and alpha {alpha!r} in (0, 1)")
    from scipy.stats import norm  # lazy, as in agreement.py: importing scipy.stats costs about a second

    z = float(norm.isf(p / 2.0))
    z_alpha = float(norm.isf(alpha / 2.0))
    same_way = float(norm.cdf((z - z_alpha) / REPLICATION_SD))
    other_way = float(norm.cdf((-z - z_alpha) / REPLICATION_SD))
    if significant:
        return same_way if directed else same_way + other_way
    return 1.0 - same_way - other_way


def band_replication(value: float, se: float, low: float, high: float) -> float:
    """Probability that a same-size replication's estimate of a published ``value`` (standard error ``se``) lands
    in [``low``, ``high``]: the estimate ~ N(value, 2·se²)."""
    if not se > 0 or not low <= high:
        raise StatsInputError(f"se {se!r} must be positive and the band [{low!r}, {high!r}] ordered")
    from scipy.stats import norm

    sd = REPLICATION_SD * se
    return float(norm.cdf((high - value) / sd) - norm.cdf((low - value) / sd))


def spread_replication(n: float, factor: float) -> float:
    """Probability that a same-size replication's SD (of ``n`` people) lies within ``factor`` of the published
    one either way: log(SD ratio) ~ N(0, 2 · 1/(2(n − 1))), the large-sample variance of a log SD twice over."""
    if not n > 1 or not factor > 1:
        raise StatsInputError(f"n {n!r} must exceed 1 and factor {factor!r} exceed 1")
    from scipy.stats import norm

    sd = math.sqrt(1.0 / (n - 1.0))
    return float(2.0 * norm.cdf(math.log(factor) / sd) - 1.0)
