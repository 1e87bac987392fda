"""Wilcoxon rank-sum / Mann-Whitney U test."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from scipy import special

from studyctl.errors import StatsInputError

from . import _exact
from ._ranks import midranks, tie_term
from ._validate import as_sample, check_alternative, check_choice
from .results import RankSumResult

_METHODS = ("auto", "exact", "asymptotic")


def normal_p(z: float, alternative: str) -> float:
    """p-value of a standard normal deviate, upper tails from ``ndtr(−z)`` (never 1 − Φ)."""
    if alternative == "greater":
        return float(special.ndtr(-z))
    if alternative == "less":
        return float(special.ndtr(z))
    return float(min(1.0, 2.0 * special.ndtr(-abs(z))))


def correction(diff: float, alternative: str, continuity: bool) -> float:
    """R's continuity correction: ±0.5 towards the null, by alternative."""
    if not continuity:
        return 0.0
    if alternative == "two-sided":
        return 0.5 * float(np.sign(diff))
    return 0.5 if alternative == "greater" else -0.5


def _u_statistic(xs: np.ndarray, ys: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """U of x, the pooled doubled mid-ranks and the tie sizes."""
    r2, _, sizes = midranks(np.concatenate((xs, ys)))
    nx = xs.size
    return float(r2[:nx].sum()) / 2.0 - nx * (nx + 1) / 2.0, r2, sizes


def _rank_biserial(u: float, nx: int, ny: int) -> float:
    return (2.0 * u - nx * ny) / (nx * ny)


def rank_biserial(xs: np.ndarray, ys: np.ndarray) -> float:
    """The effect size of :func:`rank_sum` alone, bit for bit the same, for non-empty float arrays without NaN.

    Why: a bootstrap of the effect size (``studyctl.analysis.effect_ci``) needs only this, a third of the test's
    time without its p-value and result; the test computes its effect size with the same two functions.
    """
    u, _, _ = _u_statistic(xs, ys)
    return _rank_biserial(u, xs.size, ys.size)


def rank_sum(
    x: Any,
    y: Any,
    *,
    alternative: str = "two-sided",
    method: str = "auto",
    continuity: bool = True,
) -> RankSumResult:
    r"""Wilcoxon rank-sum (Mann-Whitney U) test of x against y.

    Parameters
    ----------
    x, y : array_like
        The two independent samples. NaN (or None) values are dropped and counted in
        ``nan_dropped``; ±inf are ranked like any other value.
    alternative : {"two-sided", "less", "greater"}
        "greater": x tends to be larger than y (stochastically).
    method : {"auto", "exact", "asymptotic"}
        "auto" follows R's ``wilcox.test``: exact when both samples have fewer than 50 values and
        there are no ties, otherwise the normal approximation. "exact" with ties gives the exact
        conditional (permutation) p-value given the ties, like R's ``coin::wilcox_test(distribution
        = "exact")``; the result then has ``conditional=True``.
    continuity : bool
        Continuity correction of the normal approximation (R's ``correct=TRUE``).

    Returns
    -------
    RankSumResult
        ``statistic`` U of x, ``pvalue``, ``method`` used, ``z`` (NaN when exact), signed
        rank-biserial ``effect_size``, counts and flags. All values tied gives ``pvalue`` NaN with
        ``degenerate=True`` (as R).

    Notes
    -----
    With pooled mid-ranks R_i and tie sizes t_j,

    .. math::

        U = \sum_{i \in x} R_i - \frac{n_x(n_x+1)}{2}, \qquad
        \sigma^2 = \frac{n_x n_y}{12}\Big(N + 1 - \frac{\sum_j (t_j^3 - t_j)}{N(N-1)}\Big),

    z = (U − n_x n_y/2 − c)/σ with R's correction c. The exact untied null distribution is built by
    an all-positive recurrence and cached per (n_x, n_y); with ties the distribution of the sum of
    doubled mid-ranks over all C(N, n_x) subsets is counted exactly. One-sided p-values sum the near
    tail; the two-sided exact p is P(|U − μ| ≥ |u − μ|) (equal to R's doubled tail without ties,
    coin's definition with ties). Effect size r = 2U/(n_x n_y) − 1 (Kerby 2014).

    References
    ----------
    Mann & Whitney (1947), Ann. Math. Stat. 18:50-60. Hollander, Wolfe & Chicken (2014),
    Nonparametric Statistical Methods, 3rd ed., §4.1. R ``wilcox.test``; Hothorn et al. (2006)
    ``coin``. Kerby (2014), Comprehensive Psychology 3:11.IT.3.1.

    Examples
    --------
    >>> from studyctl.stats import rank_sum
    >>> res = rank_sum([0.80, 0.83, 1.89, 1.04, 1.45, 1.38, 1.91, 1.64, 0.73, 1.46],
    ...                [1.15, 0.88, 0.90, 0.74, 1.21], alternative="greater")
    >>> res.statistic, round(res.pvalue, 7), res.method
    (35.0, 0.1272061, 'exact')
    """
    check_alternative(alternative)
    check_choice(method, "method", _METHODS)
    xs, nan_x = as_sample(x, "x")
    ys, nan_y = as_sample(y, "y")
    nx, ny = xs.size, ys.size
    dropped = nan_x + nan_y
    warnings: list[str] = []
    if dropped:
        warnings.append(f"{dropped} missing value(s) dropped")
    if nx == 0 or ny == 0:
        raise StatsInputError(
            f"{'x' if nx == 0 else 'y'} has no non-missing values; rank_sum needs at least 1 value in each sample"
        )
    u, r2, sizes = _u_statistic(xs, ys)
    ties = bool(np.any(sizes > 1))
    n_total = nx + ny
    mu = nx * ny / 2.0
    effect = _rank_biserial(u, nx, ny)
    base = dict(
        statistic=u, alternative=alternative, effect_size=effect, n_x=nx, n_y=ny, ties=ties, nan_dropped=dropped
    )
    if sizes.size == 1:  # every value equal: the null distribution is a single point
        warnings.append("all values are tied: the test has no information (pvalue NaN)")
        return RankSumResult(
            pvalue=math.nan, method="asymptotic" if method != "exact" else "exact", z=math.nan, conditional=False,
            continuity=False, degenerate=True, warnings=tuple(warnings), **base,
        )
    if method == "auto":
        method = "exact" if (nx < 50 and ny < 50 and not ties) else "asymptotic"
        if ties and nx < 50 and ny < 50:
            warnings.append("ties: normal approximation used as in R; method='exact' gives the exact conditional p")
    if method == "exact":
        if ties:
            limit_work = (nx + 1) * n_total * (n_total * nx)
            if limit_work > 5e9:
                raise StatsInputError(
                    f"method='exact' with ties is too large here (n_x={nx}, n_y={ny}); use method='asymptotic'"
                )
            p = _tied_pvalue(r2, nx, ny, u, alternative)
        else:
            if min(nx, ny) * nx * ny > 2e9:
                raise StatsInputError(
                    f"method='exact' is too large here (n_x={nx}, n_y={ny}); use method='asymptotic'"
                )
            p = _untied_pvalue(u, nx, ny, alternative)
        return RankSumResult(
            pvalue=p, method="exact", z=math.nan, conditional=ties, continuity=False, degenerate=False,
            warnings=tuple(warnings), **base,
        )
    var = nx * ny / 12.0 * ((n_total + 1) - tie_term(sizes) / (n_total * (n_total - 1)))
    sigma = math.sqrt(var)
    diff = u - mu
    c = correction(diff, alternative, continuity)
    z = (diff - c) / sigma
    return RankSumResult(
        pvalue=normal_p(z, alternative), method="asymptotic", z=z, conditional=False, continuity=continuity,
        degenerate=False, warnings=tuple(warnings), **base,
    )


def _untied_pvalue(u: float, nx: int, ny: int, alternative: str) -> float:
    total = nx * ny
    if alternative == "less":
        return _exact.rank_sum_untied_le(u, nx, ny)
    if alternative == "greater":
        return _exact.rank_sum_untied_le(total - u, nx, ny)  # P(U ≥ u) = P(U ≤ mn − u) by symmetry
    dev = abs(u - total / 2.0)
    if dev == 0:
        return 1.0
    return min(1.0, 2.0 * _exact.rank_sum_untied_le(total / 2.0 - dev, nx, ny))


def _tied_pvalue(r2: np.ndarray, nx: int, ny: int, u: float, alternative: str) -> float:
    # T2 = doubled rank sum of x = 2U + nx(nx+1); the y-sample's T2 is the mirror image.
    n_total = nx + ny
    t2_x = int(round(2 * u)) + nx * (nx + 1)
    total2 = n_total * (n_total + 1)  # Σ of all doubled ranks

    def le_x(limit: int) -> float:
        return _exact.rank_sum_tied_le(r2, nx, limit)

    def ge_x(limit: int) -> float:  # P(T2_x ≥ limit) = P(T2_y ≤ total2 − limit)
        return _exact.rank_sum_tied_le(r2, ny, total2 - limit)

    if alternative == "less":
        return le_x(t2_x)
    if alternative == "greater":
        return ge_x(t2_x)
    mean2 = nx * (n_total + 1)  # E[T2_x]
    dev = abs(t2_x - mean2)
    if dev == 0:
        return 1.0
    return min(1.0, le_x(mean2 - dev) + ge_x(mean2 + dev))
