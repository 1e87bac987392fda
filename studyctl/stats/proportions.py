"""Wilson score interval for a proportion and Newcombe's hybrid score interval for a difference."""

from __future__ import annotations

import math
from typing import Any

from scipy import special

from studyctl.errors import StatsInputError

from ._validate import check_confidence, check_count
from .results import NewcombeInterval, WilsonInterval


def _z(confidence: float) -> float:
    return float(-special.ndtri((1.0 - confidence) / 2.0))


def _wilson(x: int, n: int, z: float) -> tuple[float, float, float]:
    if n == 0:
        return math.nan, math.nan, math.nan
    p = x / n
    z2 = z * z
    denom = n + z2
    upper = 1.0 if x == n else min(1.0, (x + z2 / 2.0 + z * math.sqrt(x * (n - x) / n + z2 / 4.0)) / denom)
    # the lower root from the product of the roots x²/(n(n+z²)): no cancellation for small x
    lower = 0.0 if x == 0 else min(p, x * x / (n * denom * upper))
    return p, max(0.0, lower), upper


def wilson_interval(successes: Any, n: Any, confidence: float = 0.95) -> WilsonInterval:
    r"""Wilson score confidence interval for a binomial proportion.

    Parameters
    ----------
    successes : int
        Number of successes x, 0 ≤ x ≤ n.
    n : int
        Number of trials (0 allowed: the interval is then NaN, e.g. a PPV with no positive calls).
    confidence : float
        Confidence level in (0, 1).

    Returns
    -------
    WilsonInterval
        ``estimate`` x/n, ``lower``, ``upper``; bounds lie exactly within [0, 1], with lower = 0 at
        x = 0 and upper = 1 at x = n.

    Notes
    -----
    .. math::

        \frac{x + z^2/2}{n + z^2} \pm \frac{z}{n + z^2}\sqrt{\frac{x(n-x)}{n} + \frac{z^2}{4}}

    with z = Φ⁻¹((1 + confidence)/2). The lower limit is computed as x²/(n(n + z²)·upper) (the
    product of the two roots), which has no cancellation for small x.

    References
    ----------
    Wilson (1927), JASA 22:209-212. Newcombe (1998), Stat. Med. 17:857-872 (method 3).

    Examples
    --------
    >>> from studyctl.stats import wilson_interval
    >>> ci = wilson_interval(50, 60)
    >>> round(ci.lower, 4), round(ci.upper, 4)
    (0.7197, 0.9069)
    """
    conf = check_confidence(confidence)
    x = check_count(successes, "successes")
    m = check_count(n, "n")
    if x > m:
        raise StatsInputError(f"successes must be between 0 and n={m}, got {x}")
    p, lo, hi = _wilson(x, m, _z(conf))
    return WilsonInterval(p, lo, hi, x, m, conf)


def newcombe_interval(x1: Any, n1: Any, x2: Any, n2: Any, confidence: float = 0.95) -> NewcombeInterval:
    r"""Newcombe's hybrid score interval (his method 10) for p1 − p2 of two independent proportions.

    Parameters
    ----------
    x1, n1 : int
        Successes and trials of group 1.
    x2, n2 : int
        Successes and trials of group 2.
    confidence : float
        Confidence level in (0, 1).

    Returns
    -------
    NewcombeInterval
        ``difference`` p1 − p2, ``lower``, ``upper``; ``margin`` is the distance from the difference
        to the limit on the side towards zero (the "CI" column of the seed 003 Table 2: for p1 > p2
        it is sqrt((p1 − l1)² + (u2 − p2)²)); NaN when the difference is 0. ``excludes_zero`` is
        true when |difference| > margin. Swapping the groups negates and swaps the limits exactly.

    Notes
    -----
    With (l_i, u_i) the Wilson limits of p_i and d = p1 − p2,

    .. math::

        L = d - \sqrt{(p_1 - l_1)^2 + (u_2 - p_2)^2},\qquad
        U = d + \sqrt{(u_1 - p_1)^2 + (p_2 - l_2)^2}.

    R's ``prop.test`` with two groups gives a Wald interval with Yates' correction, not this one.

    References
    ----------
    Newcombe (1998), Interval estimation for the difference between independent proportions:
    comparison of eleven methods. Stat. Med. 17:873-890 (method 10, Table II).

    Examples
    --------
    >>> from studyctl.stats import newcombe_interval
    >>> ci = newcombe_interval(56, 70, 48, 80)
    >>> round(ci.lower, 4), round(ci.upper, 4)
    (0.0524, 0.3339)
    """
    conf = check_confidence(confidence)
    a, m1 = check_count(x1, "x1"), check_count(n1, "n1")
    b, m2 = check_count(x2, "x2"), check_count(n2, "n2")
    if a > m1:
        raise StatsInputError(f"x1 must be between 0 and n1={m1}, got {a}")
    if b > m2:
        raise StatsInputError(f"x2 must be between 0 and n2={m2}, got {b}")
    z = _z(conf)
    p1, l1, u1 = _wilson(a, m1, z)
    p2, l2, u2 = _wilson(b, m2, z)
    d = p1 - p2
    down = math.hypot(p1 - l1, u2 - p2)
    up = math.hypot(u1 - p1, p2 - l2)
    lower, upper = d - down, d + up
    if math.isnan(d) or d == 0:
        margin = math.nan
    else:
        margin = down if d > 0 else up
    excludes = bool(lower > 0 or upper < 0)
    return NewcombeInterval(d, lower, upper, margin, excludes, p1, p2, conf)
