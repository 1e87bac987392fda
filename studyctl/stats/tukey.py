"""Tukey's honestly significant difference (Tukey-Kramer for unequal group sizes)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from ._validate import check_confidence, group_warnings
from .anova import group_stats
from .results import TukeyResult, read_only
from .studentized_range import studentized_range_ppf, studentized_range_sf


def tukey_hsd(*groups: Any, confidence: float = 0.95, names: Sequence[str] | None = None) -> TukeyResult:
    r"""Tukey HSD simultaneous comparisons of all pairs of group means (Tukey-Kramer).

    Parameters
    ----------
    *groups : array_like or a single mapping
        Two or more samples (finite numbers; NaN dropped and counted), or one ``{name: values}``
        mapping whose keys name the groups.
    confidence : float
        Family-wise confidence level of the intervals, in (0, 1).
    names : sequence of str, optional
        Group names (default "1", "2", …).

    Returns
    -------
    TukeyResult
        ``to_frame()`` has columns ``group1, group2, diff, lower, upper, p_adj``, rows in R
        ``TukeyHSD`` order (1,2), (1,3), …, (1,k), (2,3), …, with diff = mean(group2) −
        mean(group1). Zero within-group variance (MSE = 0) gives ``degenerate=True`` with p = 0
        for different means and NaN for equal means, intervals of zero width.

    Notes
    -----
    .. math::

        SE_{ij} = \sqrt{\frac{MSE}{2}\Big(\frac{1}{n_i} + \frac{1}{n_j}\Big)},\quad
        q_{ij} = |\bar x_j - \bar x_i| / SE_{ij},\quad p_{ij} = P(Q_{k, N-k} > q_{ij}),

    interval diff ± q_{1−α; k, N−k}·SE. The studentized-range survival function is computed
    directly (:func:`studentized_range_sf`), so small p-values are not rounded to 0; the quantile is
    solved to ~1e-13 and cached.

    References
    ----------
    Tukey (1953), The problem of multiple comparisons. Kramer (1956), Biometrics 12:307-310.
    R ``TukeyHSD``.

    Examples
    --------
    >>> from studyctl.stats import tukey_hsd
    >>> res = tukey_hsd({"a": [1, 2, 3], "b": [4, 5, 6], "c": [7, 8, 10]})
    >>> res.to_frame()[["group1", "group2", "diff"]].values.tolist()[0]
    ['a', 'b', 3.0]
    """
    conf = check_confidence(confidence)
    gs = group_stats(groups, names)
    warnings = group_warnings(gs.nan_dropped, gs.empty)
    k = len(gs.labels)
    df = gs.n - k
    pairs = [(i, j) for i in range(k) for j in range(i + 1, k)]
    g1 = tuple(gs.labels[i] for i, _ in pairs)
    g2 = tuple(gs.labels[j] for _, j in pairs)
    diff = np.array([gs.means[j] - gs.means[i] for i, j in pairs])
    inv = np.array([1.0 / gs.sizes[i] + 1.0 / gs.sizes[j] for i, j in pairs])
    nanv = read_only(np.full(len(pairs), np.nan))
    if k < 2 or df < 1:
        warnings.append("need at least 2 non-empty groups and more values than groups")
        return TukeyResult(g1, g2, read_only(diff), nanv, nanv, nanv, nanv, nanv, math.nan, conf, df, math.nan, k,
                           gs.nan_dropped, True, tuple(warnings))
    msw = gs.ss_within / df
    se = np.sqrt(msw / 2.0 * inv)
    q_crit = studentized_range_ppf(conf, k, df)
    degenerate = msw == 0.0
    if degenerate:
        warnings.append("zero variance within every group: p = 0 for different means, NaN for equal means")
        q = np.where(diff == 0, np.nan, np.inf)
        p = np.where(diff == 0, np.nan, 0.0)
    else:
        q = np.abs(diff) / se
        p = studentized_range_sf(q, k, df)
    half = q_crit * se
    return TukeyResult(g1, g2, read_only(diff), read_only(diff - half), read_only(diff + half), read_only(p),
                       read_only(q), read_only(se), q_crit, conf, df, msw, k, gs.nan_dropped, bool(degenerate),
                       tuple(warnings))
