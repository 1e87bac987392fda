"""Tests of means: one-way ANOVA with Tukey HSD, and the one-way repeated-measures ANOVA."""

from __future__ import annotations

import math

from studyctl import stats
from studyctl.analysis.procedures.spec import BETWEEN, WITHIN, Cell, Finding, TestSpec, below, pair_index


def _anova_oneway(cell: Cell) -> list[Finding]:
    s = stats.anova_oneway(*cell.samples).summary(effect_size=cell.effect_size or "eta_squared")
    return [Finding(s, below(s.p, cell.alpha), warnings=s.warnings)]


def _tukey_hsd(cell: Cell) -> list[Finding]:
    conf = float(cell.options.get("confidence", 0.95))
    res = stats.tukey_hsd(*cell.samples, confidence=conf, names=cell.levels)
    # Pair rows carry no result warnings (they are the procedure's, about the whole cell).
    return [
        Finding(p.summary, below(p.summary.p_adj, cell.alpha), pair=pair_index(cell.levels, p.group1, p.group2))
        for p in res.pairs()
    ]


def _rm_anova(cell: Cell) -> list[Finding]:
    s = stats.rm_anova(*cell.samples).summary()  # p: Greenhouse-Geisser corrected
    return [Finding(s, bool(s.p < cell.alpha) if math.isfinite(s.p) else None, warnings=s.warnings)]


SPECS = (
    TestSpec(
        "anova_oneway",
        BETWEEN,
        _anova_oneway,
        frozenset({"tukey_hsd"}),
        2,
        None,
        frozenset(),
        ("eta_squared", "omega_squared"),
        "one-way ANOVA F (independent samples)",
    ),
    TestSpec(
        "tukey_hsd",
        BETWEEN,
        _tukey_hsd,
        frozenset(),
        2,
        None,
        frozenset({"confidence"}),
        ("mean_difference",),
        "Tukey HSD pairwise comparisons (Tukey-Kramer for unequal sizes)",
        pairwise=True,
    ),
    TestSpec(
        "rm_anova",
        WITHIN,
        _rm_anova,
        frozenset(),
        2,
        None,
        frozenset(),
        ("partial_eta_squared",),
        "repeated-measures one-way ANOVA (participants as blocks)",
    ),
)
