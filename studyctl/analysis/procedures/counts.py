"""Pooled proportions: the Wilson interval of one level and Newcombe's interval of a difference."""

from __future__ import annotations

from studyctl import stats
from studyctl.analysis.procedures.spec import EACH_LEVEL, EACH_PAIR, PROPORTION, Cell, Finding, TestSpec


def _confidence(cell: Cell) -> float:
    return float(cell.options.get("confidence", 0.95))


def _wilson(cell: Cell) -> list[Finding]:
    ((x, n),) = cell.counts
    s = stats.wilson_interval(x, n, confidence=_confidence(cell)).summary()
    if n == 0:
        return [Finding(s, None, warnings=("no chances (n = 0): interval undefined",), status="not_computed")]
    return [Finding(s, None)]


def _newcombe(cell: Cell) -> list[Finding]:
    (x1, n1), (x2, n2) = cell.counts
    s = stats.newcombe_interval(x1, n1, x2, n2, confidence=_confidence(cell)).summary()
    d, margin = s.estimate, s.statistic
    # The margin on the side of the difference towards zero (the papers' "CI" column): a pair differs
    # when |Δp| exceeds it, i.e. when the interval excludes 0.
    if d == 0:
        return [Finding(s, False, warnings=("equal proportions: no margin towards zero (the paper prints NULL)",))]
    return [Finding(s, bool(abs(d) > margin))]


SPECS = (
    TestSpec(
        "wilson",
        PROPORTION,
        _wilson,
        frozenset(),
        1,
        None,
        frozenset({"confidence"}),
        ("proportion",),
        "Wilson score interval of a pooled proportion",
        each=EACH_LEVEL,
    ),
    TestSpec(
        "newcombe",
        PROPORTION,
        _newcombe,
        frozenset(),
        2,
        2,
        frozenset({"confidence"}),
        ("difference",),
        "Newcombe hybrid-score interval for a difference of proportions; significant when |Δp| exceeds"
        " the margin towards zero",
        each=EACH_PAIR,
    ),
)
