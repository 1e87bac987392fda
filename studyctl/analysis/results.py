"""Frozen results of running an analysis plan, with tidy ``to_frame()`` tables of fixed columns."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from functools import cached_property
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import pandas as pd

if TYPE_CHECKING:
    from studyctl.analysis.plan import AnalysisPlan
    from studyctl.analysis.table import MetricTable

NAN = math.nan

#: Columns of the tests table (one row per test, pair, interval or post-hoc comparison).
ROW_COLUMNS = (
    "test_id",
    "role",
    "kind",
    "metric",
    "test",
    "compare",
    "split",
    "groups",
    "n",
    "n_per_group",
    "statistic_name",
    "statistic",
    "df",
    "df2",
    "z",
    "p",
    "p_adj",
    "p_adjust",
    "alpha",
    "significant",
    "critical_value",
    "effect_size_name",
    "effect_size",
    "estimate",
    "ci_low",
    "ci_high",
    "ci_level",
    "method",
    "parent",
    "warnings",
    "status",
)

ROW_KINDS = ("omnibus", "two_sample", "pairwise", "posthoc", "interval", "descriptive")
STATUSES = ("ok", "not_computed", "skipped")


@dataclass(frozen=True)
class TestRow:
    """One computed (or not computable) test; ``status`` says which, ``warnings`` why."""

    test_id: str
    role: str
    kind: str
    metric: str
    test: str
    compare: str
    split: str = ""
    groups: str = ""
    n: int = 0
    n_per_group: str = ""
    statistic_name: str = ""
    statistic: float = NAN
    df: float = NAN
    df2: float = NAN
    z: float = NAN
    p: float = NAN
    p_adj: float = NAN
    p_adjust: str = "none"
    alpha: float = 0.05
    significant: bool | None = None
    critical_value: float = NAN
    effect_size_name: str = ""
    effect_size: float = NAN
    estimate: float = NAN
    ci_low: float = NAN
    ci_high: float = NAN
    ci_level: float = NAN
    method: str = ""
    parent: str = ""
    warnings: str = ""
    status: str = "ok"

    __test__ = False  # not a pytest test class

    def with_(self, **changes: object) -> TestRow:
        # replace, not asdict: every field is a plain value, and asdict deep-copies each one (a power analysis
        # adjusts thousands of rows)
        return replace(self, **changes)


@dataclass(frozen=True)
class FigureData:
    """Data a figure needs beyond the result tables (sample traces, model curves), and how to draw it.

    ``frame`` has a ``panel`` column, an ``x`` column and one column per channel; ``meta`` says which
    channels to draw (``channels``: (column, label, "left"|"right")), the x label, a shaded boolean column
    and a threshold line. ``problem`` says why the data are incomplete ('' when they are not).
    """

    frame: pd.DataFrame
    meta: Mapping[str, Any] = field(default_factory=dict)
    problem: str = ""


@dataclass(frozen=True)
class AnalysisResult:
    """Everything one plan produced from one data source.

    ``rows``: the tests table; ``tables``: extra tables by name (``descriptives``, ``percent_change``,
    ``likert``, ``cells``); ``missing``: values not available and why; ``problems``: what made the result
    partial (empty when complete); ``figures``: data of the figures drawn from stored samples or
    controllers, by figure id (when asked for: :func:`studyctl.analysis.analyze` with ``figures=True``).
    """

    plan: AnalysisPlan
    data: MetricTable
    rows: tuple[TestRow, ...]
    tables: Mapping[str, pd.DataFrame] = field(default_factory=dict)
    missing: pd.DataFrame = field(default_factory=pd.DataFrame)
    problems: tuple[str, ...] = ()
    timings: Mapping[str, float] = field(default_factory=dict)
    figures: Mapping[str, FigureData] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "tables", MappingProxyType(dict(self.tables)))
        object.__setattr__(self, "timings", MappingProxyType(dict(self.timings)))
        object.__setattr__(self, "figures", MappingProxyType(dict(self.figures)))

    @property
    def partial(self) -> bool:
        """True when something the plan asked for could not be computed."""
        return bool(self.problems) or any(r.status != "ok" for r in self.rows)

    def to_frame(self) -> pd.DataFrame:
        """The tests table, columns :data:`ROW_COLUMNS`, in plan order (a fresh copy the caller may change)."""
        return self._rows_frame.copy()

    @cached_property
    def _rows_frame(self) -> pd.DataFrame:
        # Built once per result: a report asks for the table about sixty times (headlines, methods, intervals,
        # tables), and each build deep-copies every row through ``asdict``. ``rows`` is a tuple of frozen rows, so
        # the table cannot go stale; ``dataclasses.replace`` makes a new result, which builds its own.
        return rows_frame(self.rows)

    def rows_for(self, test_id: str) -> list[TestRow]:
        return [r for r in self.rows if r.test_id == test_id]


def split_levels(split: str) -> dict[str, str]:
    """A row's ``split`` (``"group=novice, condition=linear"``, as the runner writes it) as ``{factor: level}``."""
    return dict(part.split("=", 1) for part in str(split or "").split(", ") if "=" in part)


def rows_frame(rows: Sequence[TestRow]) -> pd.DataFrame:
    """Test rows as a table with columns :data:`ROW_COLUMNS` (as :meth:`AnalysisResult.to_frame`)."""
    return pd.DataFrame([asdict(r) for r in rows], columns=list(ROW_COLUMNS))
