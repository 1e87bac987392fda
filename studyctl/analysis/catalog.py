"""What an analysis plan may ask for: the tests (their registry), aliases, option values, and the kinds
of figure.

The plan validator checks names against this catalogue (with nearest-name suggestions) and the runner
dispatches on it, so a test that is listed here is one the runner can execute. The figure kinds are
listed here and only here; the figure-data collectors and the report's drawers are keyed by them.
"""

from __future__ import annotations

from dataclasses import dataclass

from studyctl.analysis.procedures import (
    BETWEEN,
    DESCRIPTIVE,
    PROPORTION,
    REGISTRY,
    WITHIN,
    TestSpec,
)

#: The tests a plan may name, by name: the registry of :mod:`studyctl.analysis.procedures`.
TESTS: dict[str, TestSpec] = REGISTRY

ALIASES = {"mann_whitney": "rank_sum", "wilcoxon_rank_sum": "rank_sum", "wilcoxon_signed_rank": "signed_rank"}

#: Post-hoc names that are a registered test run in a variant: ``multcompare`` is Dunn's procedure as
#: MATLAB's multcompare after kruskalwallis computes it.
POSTHOC_VARIANTS = {"multcompare": ("dunn", "multcompare")}

P_ADJUST = ("none", "holm", "bonferroni", "bh")

OPTION_VALUES: dict[str, tuple[object, ...]] = {
    "alternative": ("two-sided", "less", "greater"),
    "method": ("auto", "exact", "asymptotic"),
    "zero_method": ("wilcox", "pratt", "zsplit"),
    "p_adjust": P_ADJUST,
    "variant": ("dunn", "multcompare"),
    "continuity": (True, False),
    "critical_value": (True, False),
}


# Where a figure's data come from.
FROM_RESULTS = "results"  # the analysis result's tables (units, proportions, percent change, Likert)
FROM_TRIALS = "stored trials"  # samples of stored trials (read through the study reader)
FROM_CONTROLLERS = "controllers"  # model curves: the protocol's controllers run on synthetic input


@dataclass(frozen=True)
class FigureKind:
    """One kind of figure a plan may ask for."""

    name: str
    data: str  # FROM_RESULTS, FROM_TRIALS or FROM_CONTROLLERS
    summary: str


FIGURE_KINDS: dict[str, FigureKind] = {
    k.name: k
    for k in (
        FigureKind("box", FROM_RESULTS, "box plots of a metric by condition (and group), marks from a test"),
        FigureKind(
            "proportion",
            FROM_RESULTS,
            "pooled proportion per level with Wilson intervals (detection by tumour class, Se, PPV)",
        ),
        FigureKind("percent_change", FROM_RESULTS, "bars of % change against a reference level"),
        FigureKind("likert", FROM_RESULTS, "diverging stacked bars of the answers per item and condition"),
        FigureKind(
            "force_trace", FROM_TRIALS, "sensor force and actuator commands around a tumour contact (stored samples)"
        ),
        FigureKind("needle_force_profile", FROM_TRIALS, "axial needle force against depth (stored samples)"),
        FigureKind(
            "controller_response", FROM_CONTROLLERS, "controller outputs for trapezoidal pressure waves (runs them)"
        ),
    )
}

#: Kinds whose data are collected from the study database (:mod:`studyctl.analysis.figure_data`).
SIGNAL_FIGURES = tuple(k.name for k in FIGURE_KINDS.values() if k.data != FROM_RESULTS)

__all__ = [
    "ALIASES",
    "BETWEEN",
    "DESCRIPTIVE",
    "FIGURE_KINDS",
    "OPTION_VALUES",
    "POSTHOC_VARIANTS",
    "P_ADJUST",
    "PROPORTION",
    "SIGNAL_FIGURES",
    "TESTS",
    "WITHIN",
    "FigureKind",
    "TestSpec",
]
