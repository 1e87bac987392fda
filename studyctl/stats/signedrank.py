"""Wilcoxon signed-rank test and its exact critical values."""

from __future__ import annotations

import math
from fractions import Fraction
from typing import Any

import numpy as np

from studyctl.errors import StatsInputError

from . import _exact
from ._ranks import midranks, tie_term
from ._validate import as_array, as_sample, check_alternative, check_choice, check_probability
from .ranksum import correction, normal_p
from .results import SignedRankResult

_METHODS = ("auto", "exact", "asymptotic")
_ZERO_METHODS = ("wilcox", "pratt", "zsplit")


def signed_rank(
    x: Any,
    y: Any = None,
    *,
    alternative: str = "two-sided",
    method: str = "auto",
    continuity: bool = True,
    zero_method: str = "wilcox",
    decimals: int | None = None,
) -> SignedRankResult:
    r"""Wilcoxon signed-rank test of the differences d = x − y (or of x alone).

    Parameters
    ----------
    x : array_like
        First sample, or the differences when ``y`` is None.
    y : array_like, optional
        Paired second sample, same length as ``x``. A pair with NaN on either side is dropped and
        counted in ``nan_dropped``.
    alternative : {"two-sided", "less", "greater"}
        "greater": the differences tend to be positive.
    method : {"auto", "exact", "asymptotic"}
        "auto" follows R's ``wilcox.test``: exact when there are fewer than 50 non-zero
        differences and neither ties nor zeros, else normal approximation. "exact" with ties or
        zeros gives the exact conditional (sign-flip permutation) p-value given the mid-ranks
        (``conditional=True``).
    continuity : bool
        Continuity correction of the normal approximation (R's default ``correct=TRUE``).
    zero_method : {"wilcox", "pratt", "zsplit"}
        "wilcox" drops zero differences before ranking (R); "pratt" ranks them and then drops their
        ranks (Pratt 1959, Cureton-adjusted mean/variance); "zsplit" gives half of each zero's rank
        to R+ and half to R−.
    decimals : int, optional
        Round the differences to this many decimals before zero and tie detection, so that float
        noise (0.1 + 0.2 − 0.3 = 5.6e-17) is not taken as a non-zero difference.

    Returns
    -------
    SignedRankResult
        ``statistic`` R+ (R's V), ``w_min`` = min(R+, R−), ``pvalue``, ``method``, ``z`` (NaN when
        exact), matched-pairs rank-biserial ``effect_size``, counts and flags. No non-zero
        difference gives ``pvalue`` NaN with ``degenerate=True`` (as R).

    Notes
    -----
    With mid-ranks R_i of |d_i| over the n used differences and tie sizes t_j,

    .. math::

        R^+ = \sum_{d_i > 0} R_i,\quad E = \frac{n(n+1)}{4},\quad
        \sigma^2 = \frac{n(n+1)(2n+1)}{24} - \frac{\sum_j (t_j^3 - t_j)}{48},

    z = (R+ − E − c)/σ. The exact null (each sign ± with probability ½) is the all-positive
    recurrence p_k(t) = ½p_{k−1}(t) + ½p_{k−1}(t − r_k) over the (doubled mid-)ranks; tails are
    summed on the near side and the two-sided p is P(|T − E| ≥ |t − E|). Effect size
    r = (R+ − R−)/(R+ + R−) (Kerby 2014).

    References
    ----------
    Wilcoxon (1945), Biometrics Bull. 1:80-83. Pratt (1959), JASA 54:655-667. Cureton (1967),
    JASA 62:1068-1069. R ``wilcox.test``. Kerby (2014), Comprehensive Psychology 3:11.IT.3.1.

    Examples
    --------
    >>> from studyctl.stats import signed_rank
    >>> x = [1.83, 0.50, 1.62, 2.48, 1.68, 1.88, 1.55, 3.06, 1.30]
    >>> y = [0.878, 0.647, 0.598, 2.05, 1.06, 1.29, 1.06, 3.14, 1.29]
    >>> res = signed_rank(x, y, alternative="greater")
    >>> res.statistic, res.pvalue, res.method
    (40.0, 0.01953125, 'exact')
    """
    check_alternative(alternative)
    check_choice(method, "method", _METHODS)
    check_choice(zero_method, "zero_method", _ZERO_METHODS)
    if y is None:
        d_all, dropped = as_sample(x, "x")
    else:
        # NaN stays in place so that the pairs stay aligned
        xa = as_array(x, "x")
        ya = as_array(y, "y")
        if xa.size != ya.size:
            raise StatsInputError(
                f"x and y must have the same length for paired differences, got {xa.size} and {ya.size}"
            )
        keep = ~(np.isnan(xa) | np.isnan(ya))
        dropped = int(xa.size - keep.sum())
        d_all = xa[keep] - ya[keep]
    if decimals is not None:
        d_all = np.round(d_all, int(decimals))
    warnings: list[str] = []
    if dropped:
        warnings.append(f"{dropped} missing pair(s) dropped")
    n_all = int(d_all.size)
    if n_all == 0:
        raise StatsInputError("no non-missing differences; signed_rank needs at least 1 pair")
    zero = d_all == 0
    n_zero = int(zero.sum())
    if zero_method == "wilcox":
        d = d_all[~zero]
        r2, _, sizes = midranks(np.abs(d))
        r2_used = r2
        sizes_used = sizes
        zero_r2 = np.zeros(0, dtype=np.int64)
    else:
        r2, _, sizes = midranks(np.abs(d_all))
        d = d_all[~zero]
        r2_used = r2[~zero]
        zero_r2 = r2[zero]
        sizes_used = sizes
    n_used = int(d.size)
    plus2 = int(r2_used[d > 0].sum())
    minus2 = int(r2_used[d < 0].sum())
    zsplit_half2 = int(zero_r2.sum()) if zero_method == "zsplit" else 0  # doubled ranks of zeros
    r_plus = (plus2 + zsplit_half2 / 2.0) / 2.0
    r_minus = (minus2 + zsplit_half2 / 2.0) / 2.0
    ties = bool(np.any(sizes_used[1:] > 1) if (zero_method != "wilcox" and n_zero) else np.any(sizes_used > 1))
    denom = r_plus + r_minus
    effect = (r_plus - r_minus) / denom if denom > 0 else math.nan
    base = dict(
        statistic=r_plus, w_min=min(r_plus, r_minus), alternative=alternative, zero_method=zero_method,
        effect_size=effect, n=n_all, n_used=n_used, n_zero=n_zero, ties=ties, nan_dropped=dropped,
    )
    if n_used == 0:
        warnings.append("all differences are zero: the test has no information (pvalue NaN)")
        return SignedRankResult(
            pvalue=math.nan, method="exact" if method == "exact" else "asymptotic", z=math.nan, conditional=False,
            continuity=False, degenerate=True, warnings=tuple(warnings), **base,
        )
    irregular = ties or n_zero > 0
    if method == "auto":
        method = "exact" if (n_used < 50 and not irregular) else "asymptotic"
        if irregular and n_used < 50:
            what = "ties and zeros" if (ties and n_zero) else ("ties" if ties else "zeros")
            warnings.append(
                f"{what}: normal approximation used as in R; method='exact' gives the exact conditional p"
            )
    if method == "exact":
        if n_used > 5000:
            raise StatsInputError(f"method='exact' is too large here ({n_used} differences); use method='asymptotic'")
        p = _exact_p(r2_used, plus2, irregular, n_used, alternative)
        return SignedRankResult(
            pvalue=p, method="exact", z=math.nan, conditional=irregular, continuity=False, degenerate=False,
            warnings=tuple(warnings), **base,
        )
    mean, var = _moments(n_all, n_used, n_zero, zero_method, sizes_used, zero_r2)
    if var <= 0:
        warnings.append("zero variance: every used difference is tied at the same rank pattern (pvalue NaN)")
        return SignedRankResult(
            pvalue=math.nan, method="asymptotic", z=math.nan, conditional=False, continuity=False,
            degenerate=True, warnings=tuple(warnings), **base,
        )
    diff = r_plus - mean
    c = correction(diff, alternative, continuity)
    z = (diff - c) / math.sqrt(var)
    return SignedRankResult(
        pvalue=normal_p(z, alternative), method="asymptotic", z=z, conditional=False, continuity=continuity,
        degenerate=False, warnings=tuple(warnings), **base,
    )


def _moments(
    n_all: int, n_used: int, n_zero: int, zero_method: str, sizes: np.ndarray, zero_r2: np.ndarray
) -> tuple[float, float]:
    """Null mean and variance of R+ for the chosen zero method (Cureton's adjustment for Pratt)."""
    if zero_method == "wilcox":
        n = n_used
        return n * (n + 1) / 4.0, n * (n + 1) * (2 * n + 1) / 24.0 - tie_term(sizes) / 48.0
    n = n_all
    mean = n * (n + 1) / 4.0
    var = n * (n + 1) * (2 * n + 1) / 24.0
    if zero_method == "pratt":
        z = n_zero
        mean -= z * (z + 1) / 4.0
        var -= z * (z + 1) * (2 * z + 1) / 24.0
        # zeros do not enter the tie correction: drop the zero run (the lowest ranks)
        tied = sizes[1:] if z else sizes
        return mean, var - tie_term(tied) / 48.0
    return mean, var - tie_term(sizes) / 48.0


def _exact_p(r2_used: np.ndarray, plus2: int, conditional: bool, n: int, alternative: str) -> float:
    if conditional:
        cdf = _exact.signed_rank_tied_cdf(tuple(sorted(r2_used.tolist())))
        total = int(r2_used.sum())
        t = plus2
    else:
        cdf = _exact.signed_rank_cdf(n)
        total = n * (n + 1) // 2
        t = plus2 // 2

    def le(v: int) -> float:  # P(T ≤ v), near side summed (the null is symmetric about total/2)
        if v < 0:
            return 0.0
        if v >= total:
            return 1.0
        if 2 * v <= total:
            return float(cdf[v])
        return float(1.0 - cdf[total - v - 1])  # ≥ ½ here, no relative accuracy lost

    if alternative == "less":
        return le(t)
    if alternative == "greater":
        return le(total - t)
    dev2 = abs(2 * t - total)  # in units of ½
    if dev2 == 0:
        return 1.0
    lower = (total - dev2) // 2  # largest T value with T ≤ E − |t − E|
    return min(1.0, 2.0 * le(lower))


def signed_rank_critical(n: int, alpha: float = 0.05, alternative: str = "two-sided") -> int | None:
    r"""Exact critical value of the Wilcoxon signed-rank statistic for n untied non-zero pairs.

    Parameters
    ----------
    n : int
        Number of non-zero differences (n ≥ 1).
    alpha : float
        Significance level in (0, 1).
    alternative : {"two-sided", "less", "greater"}
        Two-sided uses α/2 in the lower tail.

    Returns
    -------
    int or None
        The largest w with P(W ≤ w) ≤ α/2 (two-sided) or ≤ α (one-sided) under the exact null,
        W = min(R+, R−) for two-sided tests and the one-sided statistic otherwise; reject when the
        observed W ≤ w. ``None`` when no such w exists (n ≤ 5 two-sided at α = 0.05).

    Notes
    -----
    Exact rational arithmetic on the integer counts of the generating function ∏(1 + q^k): the
    comparison with α is not subject to rounding (α is read through its decimal representation, so
    0.05 means 1/20).

    References
    ----------
    Wilcoxon, Katti & Wilcox (1970), Critical values and probability levels for the Wilcoxon rank
    sum test and the Wilcoxon signed rank test. Selected Tables in Mathematical Statistics 1.

    Examples
    --------
    >>> from studyctl.stats import signed_rank_critical
    >>> [signed_rank_critical(n) for n in (18, 19, 20)]
    [40, 46, 52]
    """
    check_alternative(alternative)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise StatsInputError(f"n must be an integer ≥ 1, got {n!r}")
    a = check_probability(alpha, "alpha")
    level = Fraction(repr(a)) / (2 if alternative == "two-sided" else 1)
    counts = _signed_rank_counts(int(n))
    bound = level * (1 << int(n))  # P(W ≤ w) ≤ level  ⇔  cumulative count ≤ level·2^n
    cum, best = 0, None
    for w, c in enumerate(counts):
        cum += c
        if cum > bound:
            break
        best = w
    return best


def _signed_rank_counts(n: int) -> list[int]:
    counts = [1]
    for k in range(1, n + 1):
        new = counts + [0] * k
        for t, c in enumerate(counts):
            new[t + k] += c
        counts = new
    return counts
