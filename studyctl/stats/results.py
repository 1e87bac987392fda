"""Frozen result objects of the statistics layer; every one has ``to_frame()`` with fixed columns."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import pandas as pd

from .summary import PairSummary, TestSummary


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

    def summary(self) -> TestSummary:
        return TestSummary("U", float(self.statistic), p=float(self.pvalue), z=float(self.z),
                           effect_size_name="rank_biserial", effect_size=float(self.effect_size),
                           method=self.method, warnings=self.warnings)


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

    def summary(self) -> TestSummary:
        return TestSummary("V (R+)", float(self.statistic), p=float(self.pvalue), z=float(self.z),
                           effect_size_name="matched_pairs_r", effect_size=float(self.effect_size),
                           method=self.method, warnings=self.warnings)


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

    def summary(self) -> TestSummary:
        return TestSummary("H", float(self.statistic), p=float(self.pvalue), df=float(self.df),
                           effect_size_name="epsilon_squared", effect_size=float(self.effect_size),
                           method="Kruskal-Wallis, chi-squared approximation, tie-corrected", warnings=self.warnings)


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

    def summary(self, effect_size: str = "eta_squared") -> TestSummary:
        """``effect_size``: ``eta_squared`` (default) or ``omega_squared``."""
        sizes = {"eta_squared": self.eta_squared, "omega_squared": self.omega_squared}
        return TestSummary("F", float(self.statistic), p=float(self.pvalue), df=float(self.df_between),
                           df2=float(self.df_within), effect_size_name=effect_size,
                           effect_size=float(sizes[effect_size]), method="one-way ANOVA (independent samples)",
                           warnings=self.warnings)


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

    def summary(self) -> TestSummary:
        return TestSummary("chi2 (Friedman)", float(self.statistic), p=float(self.pvalue), df=float(self.df),
                           effect_size_name="kendall_w", effect_size=float(self.kendall_w),
                           method="Friedman, chi-squared approximation, tie-corrected", warnings=self.warnings)


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

    def summary(self) -> TestSummary:
        """``p`` is the Greenhouse-Geisser corrected p-value (the uncorrected one is in ``method``)."""
        return TestSummary(
            "F", float(self.statistic), p=float(self.pvalue_gg), df=float(self.df_effect),
            df2=float(self.df_error), effect_size_name="partial_eta_squared",
            effect_size=float(self.partial_eta_squared),
            method="repeated-measures ANOVA, participants "
            f"as blocks; p with the Greenhouse-Geisser correction (epsilon = {float(self.epsilon_gg):.3f}; "
            f"uncorrected p = {float(self.pvalue):.3g})",
            warnings=self.warnings,
        )


@dataclass(frozen=True)
class WilsonInterval(_OneRow):
    """Wilson score interval for a proportion (see :func:`studyctl.stats.wilson_interval`)."""

    estimate: float
    lower: float
    upper: float
    successes: int
    n: int
    confidence: float

    def summary(self) -> TestSummary:
        return TestSummary("successes", float(self.successes), estimate=float(self.estimate),
                           ci_low=float(self.lower), ci_high=float(self.upper), ci_level=float(self.confidence),
                           method="Wilson score interval")


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

    def summary(self) -> TestSummary:
        """``statistic`` is the margin towards zero: the pair differs when |Δp| exceeds it."""
        d = float(self.difference)
        return TestSummary("margin (CI towards 0)", float(self.margin), effect_size_name="difference",
                           effect_size=d, estimate=d, ci_low=float(self.lower), ci_high=float(self.upper),
                           ci_level=float(self.confidence),
                           method="Newcombe hybrid score (method 10); significant when |Δp| > margin")


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

    def pairs(self) -> tuple[PairSummary, ...]:
        """One summary per pair: z, the two-sided p, the adjusted p and the mean-rank difference."""
        if self.p_adjust == "tukey-kramer":
            method = "MATLAB multcompare after kruskalwallis (mean ranks, studentized range, df = inf)"
        else:
            method = f"Dunn z test, two-sided, {self.p_adjust} adjusted"
        return tuple(
            PairSummary(g1, g2, TestSummary(
                "z", float(self.z[i]), p=float(self.pvalue[i]), z=float(self.z[i]), p_adj=float(self.p_adj[i]),
                p_adjust=self.p_adjust, effect_size_name="mean_rank_difference",
                effect_size=float(self.mean_rank_diff[i]), method=method, warnings=self.warnings))
            for i, (g1, g2) in enumerate(zip(self.group1, self.group2, strict=True))
        )


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

    def pairs(self) -> tuple[PairSummary, ...]:
        """One summary per pair: the mean difference (second − first) with its simultaneous interval."""
        return tuple(
            PairSummary(g1, g2, TestSummary(
                "diff (second − first)", float(self.diff[i]), p_adj=float(self.p_adj[i]), p_adjust="tukey",
                effect_size_name="mean_difference", effect_size=float(self.diff[i]), estimate=float(self.diff[i]),
                ci_low=float(self.lower[i]), ci_high=float(self.upper[i]), ci_level=float(self.confidence),
                method="Tukey HSD (Tukey-Kramer), studentized range", warnings=self.warnings))
            for i, (g1, g2) in enumerate(zip(self.group1, self.group2, strict=True))
        )
