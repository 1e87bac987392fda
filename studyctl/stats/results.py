"""Frozen result objects of the statistics layer; every one has ``to_frame()`` with fixed columns."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import pandas as pd


def _cell(value: Any) -> Any:
    if isinstance(value, tuple):
        return "; ".join(str(v) for v in value)
    return value


class _OneRow:
    """``to_frame()`` for single-test results: one row, one column per dataclass field, in order."""

    def to_frame(self) -> pd.DataFrame:
        cols = [f.name for f in fields(self)]  # type: ignore[arg-type]
        return pd.DataFrame([[_cell(getattr(self, c)) for c in cols]], columns=cols)


@dataclass(frozen=True)
class RankSumResult(_OneRow):
    """Wilcoxon rank-sum / Mann-Whitney U test (see :func:`studyctl.stats.rank_sum`)."""

    statistic: float  # U of x = rank sum of x − n_x(n_x+1)/2 (R's W)
    pvalue: float
    method: str  # "exact" or "asymptotic" — what was actually used
    alternative: str
    z: float  # normal deviate when asymptotic, NaN when exact
    effect_size: float  # signed rank-biserial 2U/(n_x n_y) − 1, positive when x tends larger
    n_x: int
    n_y: int
    ties: bool  # ties present in the pooled sample
    conditional: bool  # exact p from the permutation distribution given the ties
    continuity: bool  # continuity correction applied
    nan_dropped: int
    degenerate: bool  # all values tied: no information, pvalue NaN
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class SignedRankResult(_OneRow):
    """Wilcoxon signed-rank test (see :func:`studyctl.stats.signed_rank`)."""

    statistic: float  # R+ (R's V), incl. half the zero ranks for zero_method="zsplit"
    w_min: float  # min(R+, R−), the W of printed tables
    pvalue: float
    method: str
    alternative: str
    zero_method: str
    z: float
    effect_size: float  # matched-pairs rank-biserial (R+ − R−)/(R+ + R−)
    n: int  # pairs after NaN removal (zeros included)
    n_used: int  # non-zero differences that carry a sign
    n_zero: int
    ties: bool
    conditional: bool
    continuity: bool
    nan_dropped: int
    degenerate: bool
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class KruskalResult(_OneRow):
    """Kruskal-Wallis H test (see :func:`studyctl.stats.kruskal_wallis`)."""

    statistic: float  # tie-corrected H
    df: int
    pvalue: float
    effect_size: float  # epsilon² = H / (N − 1)
    eta_squared: float  # η²_H = (H − k + 1)/(N − k), clamped at 0
    n: int
    k: int
    tie_correction: float  # C = 1 − Σ(t³−t)/(N³−N)
    nan_dropped: int
    degenerate: bool
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class AnovaResult(_OneRow):
    """One-way ANOVA (see :func:`studyctl.stats.anova_oneway`)."""

    statistic: float  # F
    df_between: int
    df_within: int
    pvalue: float
    eta_squared: float
    omega_squared: float
    ss_between: float
    ss_within: float
    ms_within: float
    n: int
    k: int
    nan_dropped: int
    degenerate: bool
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class FriedmanResult(_OneRow):
    """Friedman rank test for a complete block design (see :func:`studyctl.stats.friedman`)."""

    statistic: float  # tie-corrected chi-square
    df: int
    pvalue: float
    kendall_w: float
    n_blocks: int
    k: int
    rows_dropped: int
    degenerate: bool
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class RepeatedAnovaResult(_OneRow):
    """One-way repeated-measures ANOVA (see :func:`studyctl.stats.rm_anova`)."""

    statistic: float
    df_effect: int
    df_error: int
    pvalue: float
    epsilon_gg: float  # Greenhouse-Geisser epsilon
    pvalue_gg: float  # p with GG-corrected df
    partial_eta_squared: float
    n_subjects: int
    k: int
    rows_dropped: int
    degenerate: bool
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class WilsonInterval(_OneRow):
    """Wilson score interval for a proportion (see :func:`studyctl.stats.wilson_interval`)."""

    estimate: float
    lower: float
    upper: float
    successes: int
    n: int
    confidence: float


@dataclass(frozen=True)
class NewcombeInterval(_OneRow):
    """Newcombe hybrid score interval for p1 − p2 (see :func:`studyctl.stats.newcombe_interval`)."""

    difference: float
    lower: float
    upper: float
    margin: float  # distance from the difference to the limit on the side towards zero (NaN at 0)
    excludes_zero: bool
    p1: float
    p2: float
    confidence: float


def read_only(values: Any) -> np.ndarray:
    """A float64 copy of ``values`` that cannot be written: result arrays are immutable."""
    arr = np.array(values, dtype=np.float64)
    arr.setflags(write=False)
    return arr


class _PairTable:
    """``to_frame()`` for pairwise results: ``group1``, ``group2`` and the per-pair arrays in ``_COLUMNS``."""

    _COLUMNS: tuple[str, ...] = ()

    def to_frame(self) -> pd.DataFrame:
        cols = ["group1", "group2", *self._COLUMNS]
        data = {c: getattr(self, c) for c in cols}
        data["group1"], data["group2"] = list(data["group1"]), list(data["group2"])
        return pd.DataFrame(data, columns=cols)


@dataclass(frozen=True)
class DunnResult(_PairTable):
    """Dunn's (or MATLAB ``multcompare``-style) pairwise rank comparisons after Kruskal-Wallis.

    One entry per pair in R's order (1,2), (1,3), …, (1,k), (2,3), …; arrays are read-only.
    ``mean_rank_diff`` is mean rank of ``group1`` − mean rank of ``group2`` and ``z`` has its sign.
    """

    group1: tuple[str, ...]
    group2: tuple[str, ...]
    mean_rank_diff: np.ndarray
    z: np.ndarray
    pvalue: np.ndarray  # two-sided unadjusted, 2·Φ(−|z|)
    p_adj: np.ndarray
    p_adjust: str
    sigma2: float  # tie-corrected rank variance N(N+1)/12 − Σ(t³−t)/(12(N−1))
    n: int
    k: int
    nan_dropped: int
    degenerate: bool
    warnings: tuple[str, ...] = ()

    _COLUMNS = ("mean_rank_diff", "z", "pvalue", "p_adj")  # to_frame(): group1, group2 and these


@dataclass(frozen=True)
class TukeyResult(_PairTable):
    """Tukey HSD (Tukey-Kramer) comparisons, one entry per pair in R ``TukeyHSD`` order.

    ``diff`` is mean(group2) − mean(group1); ``lower``/``upper`` the simultaneous interval; ``p_adj``
    the studentized-range p-value. Arrays are read-only.
    """

    group1: tuple[str, ...]
    group2: tuple[str, ...]
    diff: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    p_adj: np.ndarray
    q: np.ndarray  # studentized statistic |diff| / sqrt(MSE/2 (1/n1 + 1/n2))
    se: np.ndarray  # sqrt(MSE/2 (1/n1 + 1/n2))
    q_crit: float
    confidence: float
    df: int
    ms_within: float
    k: int
    nan_dropped: int
    degenerate: bool
    warnings: tuple[str, ...] = ()

    _COLUMNS = ("diff", "lower", "upper", "p_adj")  # to_frame(): R ``TukeyHSD`` layout
