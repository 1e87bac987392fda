"""What an analysis plan may ask for: the tests, their options, post-hoc procedures and effect sizes.

The plan validator checks names against this catalogue (with nearest-name suggestions) and the runner
dispatches on it, so a test that is listed here is one the runner can execute.
"""

from __future__ import annotations

from dataclasses import dataclass

# How samples are formed from the tidy metric table.
BETWEEN = "between"  # independent samples: one value per participant (and cell), levels compared as groups
WITHIN = "within"  # paired by participant: every participant contributes to every compared level
PROPORTION = "proportion"  # pooled counts (successes / n) per level
DESCRIPTIVE = "descriptive"  # no hypothesis test


@dataclass(frozen=True)
class TestKind:
    """One test the runner knows."""

    name: str
    design: str
    min_levels: int
    max_levels: int | None  # None: any number; 2: two levels, or pairwise over `pairs`
    options: frozenset[str]
    posthoc: frozenset[str]
    effect_sizes: tuple[str, ...]  # the first is the default
    summary: str


_ALT = frozenset({"alternative"})

TESTS: dict[str, TestKind] = {
    t.name: t
    for t in (
        TestKind(
            "rank_sum",
            BETWEEN,
            2,
            2,
            _ALT | {"method", "continuity"},
            frozenset(),
            ("rank_biserial",),
            "Wilcoxon rank-sum / Mann-Whitney U (independent samples)",
        ),
        TestKind(
            "signed_rank",
            WITHIN,
            2,
            2,
            _ALT | {"method", "continuity", "zero_method", "critical_value"},
            frozenset(),
            ("matched_pairs_r",),
            "Wilcoxon signed-rank (paired by participant); optionally W against the exact W_critical",
        ),
        TestKind(
            "kruskal_wallis",
            BETWEEN,
            2,
            None,
            frozenset(),
            frozenset({"dunn", "multcompare", "rank_sum"}),
            ("epsilon_squared",),
            "Kruskal-Wallis H (independent samples)",
        ),
        TestKind(
            "anova_oneway",
            BETWEEN,
            2,
            None,
            frozenset(),
            frozenset({"tukey_hsd"}),
            ("eta_squared", "omega_squared"),
            "one-way ANOVA F (independent samples)",
        ),
        TestKind(
            "tukey_hsd",
            BETWEEN,
            2,
            None,
            frozenset({"confidence"}),
            frozenset(),
            ("mean_difference",),
            "Tukey HSD pairwise comparisons (Tukey-Kramer for unequal sizes)",
        ),
        TestKind(
            "dunn",
            BETWEEN,
            2,
            None,
            frozenset({"p_adjust", "variant"}),
            frozenset(),
            ("mean_rank_difference",),
            "Dunn's pairwise rank tests",
        ),
        TestKind(
            "friedman",
            WITHIN,
            2,
            None,
            frozenset(),
            frozenset({"signed_rank"}),
            ("kendall_w",),
            "Friedman rank test (repeated measures, complete blocks)",
        ),
        TestKind(
            "rm_anova",
            WITHIN,
            2,
            None,
            frozenset(),
            frozenset(),
            ("partial_eta_squared",),
            "repeated-measures one-way ANOVA (participants as blocks)",
        ),
        TestKind(
            "wilson",
            PROPORTION,
            1,
            None,
            frozenset({"confidence"}),
            frozenset(),
            ("proportion",),
            "Wilson score interval of a pooled proportion",
        ),
        TestKind(
            "newcombe",
            PROPORTION,
            2,
            2,
            frozenset({"confidence"}),
            frozenset(),
            ("difference",),
            "Newcombe hybrid-score interval for a difference of proportions; significant when |Δp| exceeds"
            " the margin towards zero",
        ),
        TestKind(
            "percent_change",
            DESCRIPTIVE,
            2,
            None,
            frozenset(),
            frozenset(),
            ("percent_change",),
            "percent change of the mean against a reference level",
        ),
        TestKind(
            "descriptive",
            DESCRIPTIVE,
            1,
            None,
            frozenset(),
            frozenset(),
            (),
            "n, mean, SD, SE, median and quartiles per cell",
        ),
        TestKind(
            "likert_table",
            DESCRIPTIVE,
            1,
            None,
            frozenset(),
            frozenset(),
            (),
            "mean Likert score per item and level",
        ),
    )
}

ALIASES = {"mann_whitney": "rank_sum", "wilcoxon_rank_sum": "rank_sum", "wilcoxon_signed_rank": "signed_rank"}

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
