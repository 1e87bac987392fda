"""Post-hoc pairwise rank comparisons after Kruskal-Wallis, and p-value adjustment."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import special

from ._ranks import tie_term
from ._validate import check_choice, split_groups
from .kruskal import rank_groups
from .results import DunnResult, read_only
from .studentized_range import studentized_range_sf

P_ADJUST = ("holm", "bonferroni", "bh", "sidak", "none", "tukey-kramer")


def adjust_pvalues(p: Any, method: str = "holm") -> np.ndarray:
    """Adjust p-values for multiple comparisons.

    Parameters
    ----------
    p : array_like
        Unadjusted p-values (NaN entries stay NaN and do not count).
    method : {"holm", "bonferroni", "bh", "sidak", "none"}
        Holm's step-down, Bonferroni, Benjamini-Hochberg step-up (false discovery rate), Šidák
        1 − (1 − p)^m (computed as −expm1(m·log1p(−p))), or none.

    Returns
    -------
    numpy.ndarray
        Adjusted p-values, capped at 1, in the input order; Holm is monotone in the order of the raw
        p-values (as R ``p.adjust``).

    Examples
    --------
    >>> from studyctl.stats import adjust_pvalues
    >>> adjust_pvalues([0.01, 0.04, 0.03], "holm").tolist()
    [0.03, 0.06, 0.06]
    """
    check_choice(method, "p_adjust", ("holm", "bonferroni", "bh", "sidak", "none"))
    p = np.asarray(p, dtype=np.float64)
    out = np.full(p.shape, np.nan)
    ok = ~np.isnan(p)
    pv = p[ok]
    m = pv.size
    if m == 0 or method == "none":
        out[ok] = pv
        return out
    if method == "bonferroni":
        adj = np.minimum(1.0, pv * m)
    elif method == "sidak":
        adj = np.minimum(1.0, -np.expm1(m * np.log1p(-pv)))
    elif method == "holm":
        order = np.argsort(pv, kind="stable")
        steps = np.minimum(1.0, (m - np.arange(m)) * pv[order])
        adj = np.empty(m)
        adj[order] = np.maximum.accumulate(steps)
    else:  # bh
        order = np.argsort(pv, kind="stable")[::-1]
        steps = np.minimum(1.0, m / np.arange(m, 0, -1) * pv[order])
        adj = np.empty(m)
        adj[order] = np.minimum.accumulate(steps)
    out[ok] = adj
    return out


def dunn(*groups: Any, p_adjust: str = "holm", names: Sequence[str] | None = None) -> DunnResult:
    r"""Dunn's pairwise comparisons of mean ranks after a Kruskal-Wallis test.

    Parameters
    ----------
    *groups : array_like or a single mapping
        Two or more samples, or one ``{name: values}`` mapping. NaN values are dropped before
        ranking (so NaN padding does not change anything).
    p_adjust : {"holm", "bonferroni", "bh", "sidak", "none", "tukey-kramer"}
        Multiplicity adjustment of the two-sided z-test p-values. "tukey-kramer" gives the MATLAB
        ``multcompare`` default after ``kruskalwallis``: the studentized range with k groups and
        infinite df applied to the mean ranks, p = P(Q_{k,∞} > √2·|z|).
    names : sequence of str, optional
        Group names for ``group1``/``group2`` (default "1", "2", …).

    Returns
    -------
    DunnResult
        One entry per pair (1,2), (1,3), …: ``mean_rank_diff`` (group1 − group2), ``z``, two-sided
        ``pvalue`` = 2Φ(−|z|) and ``p_adj``.

    Notes
    -----
    .. math::

        z_{ij} = \frac{\bar R_i - \bar R_j}{\sqrt{\sigma^2 (1/n_i + 1/n_j)}},\qquad
        \sigma^2 = \frac{N(N+1)}{12} - \frac{\sum (t^3 - t)}{12(N-1)}

    R ``dunn.test`` prints one-sided p = P(Z ≥ |z|) by default; here p is two-sided (as rstatix,
    SPSS, GraphPad). MATLAB's ``multcompare`` uses the same σ² (its tie adjustment equals
    Σ(t³ − t)).

    References
    ----------
    Dunn (1964), Technometrics 6:241-252. Holm (1979), Scand. J. Statist. 6:65-70. Benjamini &
    Hochberg (1995), JRSS B 57:289-300. MathWorks, ``multcompare`` documentation.

    Examples
    --------
    >>> from studyctl.stats import dunn
    >>> res = dunn([1, 2, 3, 4], [5, 6, 7, 8], [9, 10, 11, 12], p_adjust="bonferroni")
    >>> res.to_frame()[["group1", "group2"]].values.tolist()
    [['1', '2'], ['1', '3'], ['2', '3']]
    """
    check_choice(p_adjust, "p_adjust", P_ADJUST)
    labels, arrays, dropped = split_groups(groups, names, min_groups=2)
    warnings: list[str] = []
    nan_dropped = sum(dropped)
    if nan_dropped:
        warnings.append(f"{nan_dropped} missing value(s) dropped")
    keep = [i for i, a in enumerate(arrays) if a.size]
    if len(keep) < len(arrays):
        warnings.append("groups without values give NaN rows")
    k = len(arrays)
    pairs = [(i, j) for i in range(k) for j in range(i + 1, k)]
    g1 = tuple(labels[i] for i, _ in pairs)
    g2 = tuple(labels[j] for _, j in pairs)
    nanrow = read_only(np.full(len(pairs), np.nan))
    means_kept, sizes, n = rank_groups([arrays[i] for i in keep]) if keep else ([], np.zeros(0), 0)
    means = [math.nan] * k
    for i, m in zip(keep, means_kept, strict=True):
        means[i] = m
    sigma2 = n * (n + 1) / 12.0 - tie_term(sizes) / (12.0 * (n - 1)) if n > 1 else math.nan
    degenerate = not (sigma2 > 0)
    if degenerate:
        warnings.append("all values identical (zero rank variance): z and p are NaN")
        return DunnResult(g1, g2, nanrow, nanrow, nanrow, nanrow, p_adjust, sigma2, n, k, nan_dropped, True,
                          tuple(warnings))
    diff = np.array([means[i] - means[j] for i, j in pairs])
    with np.errstate(divide="ignore", invalid="ignore"):
        se = np.sqrt(sigma2 * np.array([1.0 / arrays[i].size + 1.0 / arrays[j].size for i, j in pairs]))
        z = diff / se
    p = special.erfc(np.abs(z) / math.sqrt(2.0))  # 2Φ(−|z|) without 1 − Φ
    if p_adjust == "tukey-kramer":
        p_adj = np.full(len(pairs), np.nan)
        ok = ~np.isnan(z)
        p_adj[ok] = studentized_range_sf(math.sqrt(2.0) * np.abs(z[ok]), len(keep), math.inf)
    else:
        p_adj = adjust_pvalues(p, p_adjust)
    return DunnResult(g1, g2, read_only(diff), read_only(z), read_only(p), read_only(p_adj), p_adjust, sigma2, n, k,
                      nan_dropped, False, tuple(warnings))
