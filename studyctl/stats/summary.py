"""One headline per test result: the same named fields for every test, so no caller guesses field names.

Every result class of :mod:`studyctl.stats.results` has ``summary()`` (single tests and intervals) or
``pairs()`` (pairwise procedures: one :class:`PairSummary` per compared pair). A test added later
implements the same method and is read the same way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

NAN = math.nan


@dataclass(frozen=True)
class TestSummary:
    """What a results table shows of one test or interval.

    ``statistic_name`` names ``statistic`` as it is printed (H, F, U, V (R+), …); ``df`` is NaN where the
    statistic has none (``df2``: the denominator df of an F, NaN otherwise); ``p`` is the test's own p-value (NaN
    for intervals and for procedures that only give adjusted values) and ``p_adj`` an adjusted one with its
    ``p_adjust`` method ('' when not adjusted); ``estimate`` with ``ci_low``/``ci_high`` at ``ci_level`` for
    interval results; ``method`` says how it was computed.
    """

    statistic_name: str
    statistic: float
    p: float = NAN
    df: float = NAN
    df2: float = NAN
    z: float = NAN
    p_adj: float = NAN
    p_adjust: str = ""
    effect_size_name: str = ""
    effect_size: float = NAN
    estimate: float = NAN
    ci_low: float = NAN
    ci_high: float = NAN
    ci_level: float = NAN
    method: str = ""
    warnings: tuple[str, ...] = ()

    __test__ = False  # not a pytest test class


@dataclass(frozen=True)
class PairSummary:
    """One pair of a pairwise procedure: the two group names (as given to the test) and its summary."""

    group1: str
    group2: str
    summary: TestSummary
