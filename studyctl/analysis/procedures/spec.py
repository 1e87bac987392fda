"""What a registered test is (:class:`TestSpec`), what it is given (:class:`Cell`) and what it returns
(:class:`Finding`): the contract between the plan runner and every test.

The runner (:mod:`studyctl.analysis.execute`) shapes the data of one cell for the test's ``design``,
calls ``run`` once per cell, per pair of levels or per level (``each``), and turns each finding into a
row of the tests table from its one typed :class:`~studyctl.stats.TestSummary`. A test therefore never
sees the metric table and the runner never looks at a test's own result fields.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from studyctl.errors import StatsInputError
from studyctl.stats import TestSummary

# How samples are formed from the tidy metric table.
BETWEEN = "between"  # independent samples: one value per participant (and cell), levels compared as groups
WITHIN = "within"  # paired by participant: every participant contributes to every compared level
PROPORTION = "proportion"  # pooled counts (successes / n) per level
DESCRIPTIVE = "descriptive"  # no hypothesis test: rows of a result table

# How often ``run`` is called for one cell of a plan entry.
EACH_CELL = "cell"  # once with every level (omnibus tests, pairwise procedures such as Tukey HSD)
EACH_PAIR = "pair"  # once per pair of levels (two-sample tests, differences of proportions)
EACH_LEVEL = "level"  # once per level (intervals of one proportion)

NAN = math.nan


@dataclass(frozen=True)
class Cell:
    """The data of one call of a test, shaped by the runner for the test's design.

    ``samples``: BETWEEN, the finite values of each level; WITHIN, one column per level of the complete
    blocks (participants with a value in every level, same order in every column); DESCRIPTIVE, every
    value of each level (NaN kept). ``counts``: PROPORTION, (successes, chances) per level.
    ``options`` are the plan entry's options (post-hoc runs get the post-hoc's), ``alpha`` its level,
    ``effect_size`` the effect size it asked for first (None: the test's default), ``reference`` the
    reference level of a comparison against one level. ``units`` are the cell's rows of the units table
    (``participant``, ``group``, ``condition``, ``level``, ``value``; for proportions ``successes`` and
    ``chances``), for tests that need more than one array per level (models with participants as a
    random factor, aligned-rank transforms over a second factor); a test of a pair of levels gets the whole
    cell's rows and keeps those of its ``levels``.
    """

    levels: tuple[str, ...]
    alpha: float
    samples: tuple[np.ndarray, ...] = ()
    counts: tuple[tuple[int, int], ...] = ()
    options: Mapping[str, Any] = field(default_factory=dict)
    effect_size: str | None = None
    reference: str | None = None
    units: pd.DataFrame | None = field(default=None, repr=False)
    compare: str = ""  # the compared factor's name (condition, group or a metric's level such as item)


@dataclass(frozen=True)
class Finding:
    """One row's worth of a test: its summary and its verdict.

    ``pair`` are the indices (into ``Cell.levels``) of the two levels a pairwise procedure compared
    (None: the finding is about the whole call). ``significant`` is the test's own decision at
    ``Cell.alpha`` (None: no decision, e.g. an interval). ``test`` and ``p_adjust`` name the row's test
    and adjustment when they are not the registered name and the summary's. ``warnings`` are the test's
    notes, shown after the runner's data notes.
    """

    summary: TestSummary
    significant: bool | None
    pair: tuple[int, int] | None = None
    test: str = ""
    p_adjust: str = ""
    critical_value: float = NAN
    warnings: tuple[str, ...] = ()
    status: str = "ok"
    term: str = ""  # the model term of this finding (models give one finding per term)


Run = Callable[[Cell], Sequence[Finding]]
Tabulate = Callable[[Cell], Sequence[Mapping[str, Any]]]


@dataclass(frozen=True)
class TestSpec:
    """One test the runner knows: how its data are formed, how it runs, and what a plan may set.

    ``run`` returns findings (hypothesis tests, intervals); a DESCRIPTIVE entry has ``tabulate``
    instead, whose rows (one per level, starting with ``level``) go to the result table ``table``.
    ``posthoc`` names the tests a plan may run after it; ``options`` the plan options it reads;
    ``effect_sizes`` what it can report (the first is the default). A ``pairwise`` procedure compares
    every pair of a cell's levels in one call (its findings name their ``pair``); after an omnibus test
    it runs on the same cell, while a two-level test (``each = EACH_PAIR``) runs once per pair and its
    p-values are adjusted by the runner.
    """

    name: str
    design: str
    run: Run | None
    posthoc: frozenset[str]
    min_levels: int
    max_levels: int | None  # None: any number; 2: two levels, or pairwise over `pairs`
    options: frozenset[str]
    effect_sizes: tuple[str, ...]
    summary: str
    each: str = EACH_CELL
    pairwise: bool = False  # a pairwise procedure: only pair findings, no omnibus row (Tukey HSD, Dunn)
    tabulate: Tabulate | None = None
    table: str = ""

    __test__ = False  # not a pytest test class


def below(p: float, alpha: float) -> bool:
    """The usual decision: significant when p < alpha (False for an undefined p)."""
    return bool(p < alpha)


def pair_index(levels: Sequence[str], group1: str, group2: str) -> tuple[int, int]:
    """Indices of a pairwise result's two groups among ``levels`` (the names the test was given)."""
    try:
        return list(levels).index(group1), list(levels).index(group2)
    except ValueError:
        raise StatsInputError(f"pairwise result names an unknown group ({group1!r}, {group2!r})") from None
