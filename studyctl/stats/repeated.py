"""Within-subject tests: Friedman and one-way repeated-measures ANOVA.

The seed papers analysed their within-subject designs with between-subject tests; these give the
matching within-subject analysis so a report can show both.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy import special

from studyctl.errors import StatsInputError

from .results import FriedmanResult, RepeatedAnovaResult


def _matrix(conditions: tuple[Any, ...], names: Sequence[str] | None) -> tuple[np.ndarray, int]:
    """Subjects × conditions matrix from one sequence per condition; rows with NaN dropped."""
    if len(conditions) == 1 and isinstance(conditions[0], dict):
        conditions = tuple(conditions[0].values())
    if len(conditions) == 1:
        arr = np.asarray(conditions[0], dtype=object)
        if arr.ndim == 2:
            conditions = tuple(arr.T)
    if len(conditions) < 2:
        raise StatsInputError(f"need at least 2 conditions (one sequence per condition), got {len(conditions)}")
    if names is not None and len(names) != len(conditions):
        raise StatsInputError(f"names has {len(names)} entries but there are {len(conditions)} conditions")
    cols = []
    for i, c in enumerate(conditions):
        try:
            col = np.asarray(c, dtype=np.float64)
        except (TypeError, ValueError):
            raise StatsInputError(f"condition {i + 1} must contain only numbers (NaN for missing)") from None
        if col.ndim != 1 or col.size == 0:
            raise StatsInputError(f"condition {i + 1} must be a non-empty 1-D sequence, got shape {col.shape}")
        cols.append(col)
    lengths = {c.size for c in cols}
    if len(lengths) != 1:
        raise StatsInputError(
            f"every condition needs one value per subject; got lengths {[c.size for c in cols]}"
        )
    y = np.column_stack(cols)
    if np.any(np.isinf(y)):
        raise StatsInputError("values must be finite (NaN marks a missing value)")
    ok = ~np.isnan(y).any(axis=1)
    return y[ok], int((~ok).sum())


def _row_midranks(y: np.ndarray) -> tuple[np.ndarray, float]:
    """Within-row mid-ranks of ``y`` (n × k, no NaN) and Σ(t³ − t) over every row's tie groups, without a
    Python loop over rows (the effect-size bootstrap runs Friedman thousands of times per report).

    A value's mid-rank is (values below it) + (values equal to it, itself included, + 1) / 2; a tie group of
    t values gives each of them t² − 1, so the group contributes t³ − t. Both are exact in float64 (halves
    and small integers), hence the same numbers as ``scipy.stats.rankdata`` and a per-row ``tie_term``.
    """
    below = (y[:, None, :] < y[:, :, None]).sum(axis=2)
    equal = (y[:, None, :] == y[:, :, None]).sum(axis=2)
    ranks = below + (equal + 1) / 2.0
    return ranks, float(int((equal * equal - 1).sum()))


def friedman(*conditions: Any, names: Sequence[str] | None = None) -> FriedmanResult:
    r"""Friedman rank test for k related samples (each subject measured under every condition).

    Parameters
    ----------
    *conditions : array_like
        One sequence per condition, aligned by subject (or one n × k array / ``{name: values}``
        mapping). Subjects with a missing value are dropped (``rows_dropped``).
    names : sequence of str, optional
        Condition names.

    Returns
    -------
    FriedmanResult
        Tie-corrected ``statistic``, ``df`` = k − 1, ``pvalue`` (χ² upper tail), Kendall's W.
        All rows constant gives NaN with ``degenerate=True``.

    Notes
    -----
    With within-subject mid-ranks and column rank sums R_j over n subjects,

    .. math::

        Q = \frac{12 \sum_j (R_j - n(k+1)/2)^2 / (n k (k+1))}{1 - \sum (t^3 - t) / (n (k^3 - k))},
        \qquad W = Q / (n (k - 1)).

    References
    ----------
    Friedman (1937), JASA 32:675-701. R ``friedman.test``.

    Examples
    --------
    >>> from studyctl.stats import friedman
    >>> res = friedman([1, 2, 3, 4], [2, 3, 4, 5], [3, 4, 5, 6])
    >>> res.statistic
    8.0
    """
    y, dropped = _matrix(conditions, names)
    n, k = y.shape
    nan = math.nan
    warnings: list[str] = [f"{dropped} subject(s) with missing values dropped"] if dropped else []
    if n < 1:
        return FriedmanResult(nan, k - 1, nan, nan, n, k, dropped, True, (*warnings, "no complete subjects"))
    ranks, ties = _row_midranks(y)
    rsum = ranks.sum(axis=0)
    num = 12.0 * math.fsum((r - n * (k + 1) / 2.0) ** 2 for r in rsum) / (n * k * (k + 1))
    c = 1.0 - ties / (n * (k**3 - k))
    if c <= 0:
        return FriedmanResult(nan, k - 1, nan, nan, n, k, dropped, True,
                              (*warnings, "every subject has the same value in all conditions"))
    q = num / c
    return FriedmanResult(q, k - 1, float(special.chdtrc(k - 1, q)), q / (n * (k - 1)), n, k, dropped, False,
                          tuple(warnings))


def rm_anova(*conditions: Any, names: Sequence[str] | None = None) -> RepeatedAnovaResult:
    r"""One-way repeated-measures ANOVA with the Greenhouse-Geisser correction.

    Parameters
    ----------
    *conditions : array_like
        One sequence per condition aligned by subject (or one n × k array / mapping). Subjects
        with a missing value are dropped (``rows_dropped``); the design must then be complete.
    names : sequence of str, optional
        Condition names.

    Returns
    -------
    RepeatedAnovaResult
        ``statistic`` F, ``df_effect`` = k − 1, ``df_error`` = (k − 1)(n − 1), ``pvalue``,
        Greenhouse-Geisser ``epsilon_gg`` and ``pvalue_gg``, partial η².

    Notes
    -----
    With residuals e_ij = y_ij − ȳ_i· − ȳ_·j + ȳ (computed directly, not by subtracting sums of
    squares), F = [n Σ_j (ȳ_·j − ȳ)²/(k − 1)] / [Σ e²/((k − 1)(n − 1))];
    ε_GG = tr(S̃)² / ((k − 1) tr(S̃²)) from the double-centred covariance S̃ of the conditions.
    Agrees with statsmodels ``AnovaRM`` (tests).

    References
    ----------
    Greenhouse & Geisser (1959), Psychometrika 24:95-112. Maxwell & Delaney (2004), Designing
    Experiments and Analyzing Data, ch. 11.

    Examples
    --------
    >>> from studyctl.stats import rm_anova
    >>> res = rm_anova([1, 2, 3, 4], [2, 4, 3, 5], [3, 5, 6, 5])
    >>> res.df_effect, res.df_error
    (2, 6)
    """
    y, dropped = _matrix(conditions, names)
    n, k = y.shape
    nan = math.nan
    warnings: list[str] = [f"{dropped} subject(s) with missing values dropped"] if dropped else []
    df_e, df_r = k - 1, (k - 1) * (n - 1)
    if n < 2:
        return RepeatedAnovaResult(nan, df_e, df_r, nan, nan, nan, nan, n, k, dropped, True,
                                   (*warnings, "need at least 2 complete subjects"))
    y, ss_cond, ss_err, no_residual = _sums_of_squares(y)
    if no_residual:
        f = math.inf if ss_cond > 0 else nan
        return RepeatedAnovaResult(f, df_e, df_r, 0.0 if ss_cond > 0 else nan, nan, 0.0 if ss_cond > 0 else nan,
                                   _partial_eta_squared(ss_cond, ss_err, no_residual), n, k, dropped, True,
                                   (*warnings, "zero residual variance"))
    f = (ss_cond / df_e) / (ss_err / df_r)
    p = float(special.fdtrc(df_e, df_r, f))
    s = np.cov(y, rowvar=False)
    j = np.eye(k) - 1.0 / k
    sc = j @ s @ j
    eps = float(np.trace(sc) ** 2 / ((k - 1) * np.sum(sc * sc)))
    eps = min(1.0, max(1.0 / (k - 1), eps))
    p_gg = float(special.fdtrc(eps * df_e, eps * df_r, f))
    return RepeatedAnovaResult(f, df_e, df_r, p, eps, p_gg, _partial_eta_squared(ss_cond, ss_err, no_residual), n,
                               k, dropped, False, tuple(warnings))


def _sums_of_squares(y: np.ndarray) -> tuple[np.ndarray, float, float, bool]:
    """``y`` (subjects × conditions) centred on its median, SS of conditions, SS of error, and whether the residual
    is zero."""
    y = y - np.median(y)
    grand = y.mean()
    cm = y.mean(axis=0)
    sm = y.mean(axis=1)
    ss_cond = y.shape[0] * float(np.sum((cm - grand) ** 2))
    resid = y - sm[:, None] - cm[None, :] + grand
    ss_err = float(np.sum(resid**2))
    # Identical subjects leave a residual of rounding error only (3.666… repeated gives ~1e-31, not 0):
    # an F of 1e30 and a Greenhouse-Geisser 0/0. Below a few ulps of the total sum of squares it is zero.
    return y, ss_cond, ss_err, ss_err <= 64 * np.finfo(float).eps * float(np.sum((y - grand) ** 2))


def _partial_eta_squared(ss_cond: float, ss_err: float, no_residual: bool) -> float:
    if no_residual:
        return 1.0 if ss_cond > 0 else math.nan
    return ss_cond / (ss_cond + ss_err)


def rm_partial_eta_squared(*conditions: np.ndarray) -> float:
    """The effect size of :func:`rm_anova` alone, bit for bit the same, for two or more equally long float arrays
    (one per condition, a subject per position) without NaN.

    Why: a bootstrap of the effect size (``studyctl.analysis.effect_ci``) needs only this, without the
    Greenhouse-Geisser correction and p-values; the test computes its effect size with the same functions.
    """
    y = np.column_stack(conditions)
    if y.shape[0] < 2:
        return math.nan
    _, ss_cond, ss_err, no_residual = _sums_of_squares(y)
    return _partial_eta_squared(ss_cond, ss_err, no_residual)
