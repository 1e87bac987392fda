"""studyctl.stats — exact, fast and numerically stable tests and intervals that reproduce R.

Every function takes plain sequences/arrays (NaN = missing, dropped and counted) and returns a
frozen dataclass with named fields and ``to_frame()`` with fixed columns. Bad input raises
:class:`studyctl.errors.StatsInputError` naming the argument and the allowed range; degenerate data
(all values tied, zero variance) return NaN or a documented value with ``degenerate=True`` and a
message in ``warnings``.

Tests: :func:`rank_sum`, :func:`signed_rank`, :func:`signed_rank_critical`,
:func:`kruskal_wallis`, :func:`dunn`, :func:`anova_oneway`, :func:`tukey_hsd`, :func:`friedman`,
:func:`rm_anova`. Intervals: :func:`wilson_interval`, :func:`newcombe_interval`. Helpers:
:func:`adjust_pvalues`, :func:`studentized_range_sf`, :func:`studentized_range_ppf`. Every result reads
the same way through ``summary()`` (a :class:`TestSummary`) or, for pairwise procedures, ``pairs()``.
"""

from .anova import anova_oneway
from .kruskal import kruskal_wallis
from .posthoc import adjust_pvalues, dunn
from .proportions import newcombe_interval, wilson_interval
from .ranksum import rank_sum
from .repeated import friedman, rm_anova
from .results import (
    AnovaResult,
    DunnResult,
    FriedmanResult,
    KruskalResult,
    NewcombeInterval,
    RankSumResult,
    RepeatedAnovaResult,
    SignedRankResult,
    TukeyResult,
    WilsonInterval,
)
from .signedrank import signed_rank, signed_rank_critical
from .studentized_range import studentized_range_ppf, studentized_range_sf
from .summary import PairSummary, TestSummary
from .tukey import tukey_hsd

__all__ = [
    "AnovaResult",
    "DunnResult",
    "FriedmanResult",
    "KruskalResult",
    "NewcombeInterval",
    "PairSummary",
    "RankSumResult",
    "RepeatedAnovaResult",
    "SignedRankResult",
    "TestSummary",
    "TukeyResult",
    "WilsonInterval",
    "adjust_pvalues",
    "anova_oneway",
    "dunn",
    "friedman",
    "kruskal_wallis",
    "newcombe_interval",
    "rank_sum",
    "rm_anova",
    "signed_rank",
    "signed_rank_critical",
    "studentized_range_ppf",
    "studentized_range_sf",
    "tukey_hsd",
    "wilson_interval",
]
