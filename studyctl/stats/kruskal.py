"""Kruskal-Wallis H test."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import special

from ._ranks import midranks, tie_term
from ._validate import group_warnings, split_groups
from .results import KruskalResult


def rank_groups(arrays: list[np.ndarray]) -> tuple[list[float], np.ndarray, int]:
    """Mean mid-rank of each group in the pooled ranking, tie sizes, and N (one sort)."""
    pooled = np.concatenate(arrays)
    r2, _, sizes = midranks(pooled)
    bounds = np.cumsum([0] + [a.size for a in arrays])
    # doubled ranks are integers, so each group's rank sum is exact
    means = [float(r2[bounds[i] : bounds[i + 1]].sum()) / (2.0 * arrays[i].size) for i in range(len(arrays))]
    return means, sizes, int(pooled.size)


def _h_parts(arrays: list[np.ndarray]) -> tuple[float, float, int]:
    """H before the tie correction, the tie correction C, and N."""
    means, sizes, n = rank_groups(arrays)
    c = 1.0 - tie_term(sizes) / (float(n) ** 3 - n)
    centre = (n + 1) / 2.0
    h_raw = 12.0 / (n * (n + 1)) * math.fsum(a.size * (m - centre) ** 2 for a, m in zip(arrays, means, strict=True))
    return h_raw, c, n


def _epsilon_squared(h: float, n: int) -> float:
    return h / (n - 1)


def epsilon_squared(*arrays: np.ndarray) -> float:
    """The effect size of :func:`kruskal_wallis` alone, bit for bit the same (NaN where the test's is: all values
    tied), for two or more non-empty float arrays without NaN.

    Why: a bootstrap of the effect size (``studyctl.analysis.effect_ci``) needs only this; the test computes its
    effect size with the same functions.
    """
    h_raw, c, n = _h_parts(list(arrays))
    return math.nan if c <= 0 else _epsilon_squared(h_raw / c, n)


def kruskal_wallis(*groups: Any, names: Sequence[str] | None = None) -> KruskalResult:
    r"""Kruskal-Wallis rank test that k independent samples come from the same distribution.

    Parameters
    ----------
    *groups : array_like or a single mapping
        Two or more samples, or one ``{name: values}`` mapping. NaN values are dropped
        (``nan_dropped``); a group left empty is excluded with a warning.
    names : sequence of str, optional
        Group names (for messages; the result does not depend on them or on group order).

    Returns
    -------
    KruskalResult
        Tie-corrected ``statistic`` H, ``df`` = k − 1, ``pvalue`` from the χ² upper tail,
        ``effect_size`` ε² = H/(N − 1), ``eta_squared`` η²_H = (H − k + 1)/(N − k) clamped at 0.
        All values identical: H and p are NaN with ``degenerate=True``.

    Notes
    -----
    .. math::

        H = \frac{12}{N(N+1)} \sum_i n_i \Big(\bar R_i - \frac{N+1}{2}\Big)^2 \Big/
        \Big(1 - \frac{\sum_j (t_j^3 - t_j)}{N^3 - N}\Big)

    The centred form cannot go negative (identical groups give H = 0 exactly); group terms are
    added with ``math.fsum`` so group order does not change a bit of the result; p = χ²_{k−1} SF.

    References
    ----------
    Kruskal & Wallis (1952), JASA 47:583-621. Tomczak & Tomczak (2014), Trends Sport Sci. 21:19-25
    (ε²). R ``kruskal.test``.

    Examples
    --------
    >>> from studyctl.stats import kruskal_wallis
    >>> res = kruskal_wallis([1, 1, 1], [2, 2, 2], [2, 2])
    >>> round(res.statistic, 6), round(res.pvalue, 6)
    (7.0, 0.030197)
    """
    labels, arrays, dropped = split_groups(groups, names, min_groups=2)
    nan_dropped = sum(dropped)
    empty = [lab for lab, a in zip(labels, arrays, strict=True) if a.size == 0]
    warnings = group_warnings(nan_dropped, empty)
    arrays = [a for a in arrays if a.size]
    k = len(arrays)
    nan = math.nan
    if k < 2:
        warnings.append("fewer than 2 non-empty groups: nothing to compare")
        n = sum(a.size for a in arrays)
        return KruskalResult(nan, max(k - 1, 0), nan, nan, nan, n, k, nan, nan_dropped, True, tuple(warnings))
    h_raw, c, n = _h_parts(arrays)
    if c <= 0:
        warnings.append("all values are identical: H is 0/0 (NaN)")
        return KruskalResult(nan, k - 1, nan, nan, nan, n, k, c, nan_dropped, True, tuple(warnings))
    h = h_raw / c
    p = float(special.chdtrc(k - 1, h))
    eps2 = _epsilon_squared(h, n)
    eta2 = max(0.0, (h - k + 1) / (n - k)) if n > k else nan
    return KruskalResult(h, k - 1, p, eps2, eta2, n, k, c, nan_dropped, False, tuple(warnings))
