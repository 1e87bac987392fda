"""One-way ANOVA with data centred before any sum of squares."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import special

from ._validate import group_warnings, split_groups
from .results import AnovaResult


@dataclass(frozen=True)
class GroupStats:
    """Per-group sizes and means of centred data plus the pooled within-group sum of squares."""

    labels: list[str]
    sizes: np.ndarray
    means: np.ndarray  # means of (x − centre)
    centre: float
    ss_between: float
    ss_within: float
    n: int
    nan_dropped: int
    empty: list[str]


def group_stats(groups: tuple[Any, ...], names: Sequence[str] | None) -> GroupStats:
    labels, arrays, dropped = split_groups(groups, names, min_groups=2, allow_inf=False)
    empty = [lab for lab, a in zip(labels, arrays, strict=True) if a.size == 0]
    kept = [(lab, a) for lab, a in zip(labels, arrays, strict=True) if a.size]
    labels = [lab for lab, _ in kept]
    arrays = [a for _, a in kept]
    if not arrays:
        return GroupStats(labels, np.zeros(0), np.zeros(0), 0.0, math.nan, math.nan, 0, sum(dropped), empty)
    pooled = np.concatenate(arrays)
    # Centre on a data value (the median) so that x − c is exact for data near c: sums of squares
    # then do not depend on a constant offset such as 1e9 or 1e12.
    centre = float(np.median(pooled))
    centred = [a - centre for a in arrays]
    sizes = np.array([a.size for a in arrays], dtype=np.int64)
    means = np.array([math.fsum(c) / c.size for c in centred])
    n = int(sizes.sum())
    grand = math.fsum(float(s) * m for s, m in zip(sizes, means, strict=True)) / n
    # fsum over groups: the result is the same whatever order the groups come in
    ss_between = math.fsum(float(s) * (m - grand) ** 2 for s, m in zip(sizes, means, strict=True))
    ss_within = math.fsum(float(np.sum((c - m) ** 2)) for c, m in zip(centred, means, strict=True))
    return GroupStats(labels, sizes, means, centre, ss_between, ss_within, n, sum(dropped), empty)


def anova_oneway(*groups: Any, names: Sequence[str] | None = None) -> AnovaResult:
    r"""One-way between-subjects analysis of variance.

    Parameters
    ----------
    *groups : array_like or a single mapping
        Two or more samples (finite numbers; NaN dropped and counted), or one ``{name: values}``
        mapping. Groups left empty are excluded with a warning.
    names : sequence of str, optional
        Group names.

    Returns
    -------
    AnovaResult
        ``statistic`` F, ``df_between`` = k − 1, ``df_within`` = N − k, ``pvalue`` (F upper tail),
        η² = SS_B/SS_T and ω² = (SS_B − (k−1)MS_W)/(SS_T + MS_W). Zero within-group variance with
        different means gives F = inf, p = 0 and ``degenerate=True``; all values identical gives NaN.

    Notes
    -----
    .. math::

        F = \frac{\sum_i n_i (\bar x_i - \bar x)^2 / (k-1)}{\sum_i \sum_j (x_{ij} - \bar x_i)^2 / (N-k)}

    Data are centred on their median before squaring, and group terms are added with ``math.fsum``,
    so F is unchanged by adding 1e9 or 1e12 to every value or by reordering the groups.

    References
    ----------
    Fisher (1925), Statistical Methods for Research Workers. Olejnik & Algina (2003),
    Psychol. Methods 8:434-447 (ω²). R ``oneway.test(var.equal=TRUE)`` / ``aov``.

    Examples
    --------
    >>> from studyctl.stats import anova_oneway
    >>> res = anova_oneway([1, 2, 3], [4, 5, 6])
    >>> res.statistic, round(res.pvalue, 7)
    (13.5, 0.0213116)
    """
    gs = group_stats(groups, names)
    warnings = group_warnings(gs.nan_dropped, gs.empty)
    k = len(gs.labels)
    n = gs.n
    nan = math.nan
    df_b, df_w = k - 1, n - k
    if k < 2 or df_w < 1:
        warnings.append("need at least 2 non-empty groups and more values than groups")
        return AnovaResult(nan, df_b, df_w, nan, nan, nan, gs.ss_between, gs.ss_within, nan, n, k, gs.nan_dropped,
                           True, tuple(warnings))
    ssb, ssw = gs.ss_between, gs.ss_within
    msw = ssw / df_w
    sst = ssb + ssw
    if ssw == 0.0:
        if ssb == 0.0:
            warnings.append("all values identical: F is 0/0 (NaN)")
            return AnovaResult(nan, df_b, df_w, nan, nan, nan, ssb, ssw, msw, n, k, gs.nan_dropped, True,
                               tuple(warnings))
        warnings.append("zero variance within every group but different means: F = inf, p = 0")
        return AnovaResult(math.inf, df_b, df_w, 0.0, 1.0, 1.0, ssb, ssw, msw, n, k, gs.nan_dropped, True,
                           tuple(warnings))
    f = (ssb / df_b) / msw
    p = float(special.fdtrc(df_b, df_w, f))
    eta2 = ssb / sst
    omega2 = (ssb - df_b * msw) / (sst + msw)
    return AnovaResult(f, df_b, df_w, p, eta2, omega2, ssb, ssw, msw, n, k, gs.nan_dropped, False, tuple(warnings))
