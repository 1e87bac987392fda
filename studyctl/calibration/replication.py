"""How often a same-size replication of a published test gives the published verdict (pure computation).

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
