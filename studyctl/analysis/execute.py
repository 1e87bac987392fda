"""Run an analysis plan's tests on a metric table and collect one tidy row per test.

This module shapes the data of each plan entry into cells (metric × split, levels ordered as the plan
says), dispatches every cell to the entry's test in the registry (:mod:`studyctl.analysis.procedures`),
turns each finding's typed summary into a row, and adjusts p-values across an entry's rows and across a
post-hoc test's pairs (:func:`~studyctl.stats.adjust_pvalues`). It knows no test by name.

A test that cannot be computed (too few values, a constant sample, pooled counts where per-participant
values are needed) still gets its row, with ``status = "not_computed"`` and the reason in ``warnings``,
so a partial result is visibly partial.
"""

from __future__ import annotations

import dataclasses
import itertools
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pandas as pd

from studyctl.analysis import catalog
from studyctl.analysis.plan import AnalysisPlan, PlanTest, Posthoc
from studyctl.analysis.procedures import EACH_LEVEL, EACH_PAIR, Cell, Finding, TestSpec
from studyctl.analysis.result_tables import cells_table, proportions_table, units_table
from studyctl.analysis.results import AnalysisResult, TestRow
from studyctl.analysis.shape import (
    Blocks,
    Prepared,
    factor_column,
    ordered_levels,
    pooled_counts,
    prepare,
    unit_values,
)
from studyctl.analysis.table import MetricTable
from studyctl.errors import StudyctlError
from studyctl.stats.posthoc import adjust_pvalues
from studyctl.stats.summary import TestSummary

#: the row columns a finding's typed summary fills as they are (its p_adjust and warnings are merged with the entry's)
_SUMMARY_COLUMNS = tuple(
    f.name for f in dataclasses.fields(TestSummary) if f.name not in ("p_adjust", "warnings")
)


def _join(*parts: Sequence[str]) -> str:
    return "; ".join(w for part in parts for w in part)


#: Where a test's units come from: ``(metric, kind, keep, aggregate, data) → unit rows``, equal to
#: :func:`~studyctl.analysis.shape.unit_values` of ``data`` (a power analysis drawing people from a pool passes
#: one that looks up each person's units, computed once per person).
UnitSource = Callable[[str, str, list[str], str, pd.DataFrame], pd.DataFrame]


def is_hypothesis_entry(entry: PlanTest) -> bool:
    """Does this plan entry test a hypothesis (not a table of descriptives, not intervals of each level)?"""
    spec = catalog.TESTS[catalog.ALIASES.get(entry.test, entry.test)]
    return spec.design != catalog.DESCRIPTIVE and not (spec.design == catalog.PROPORTION and spec.each == EACH_LEVEL)


class _EntryRunner:
    """Runs one plan entry (one test family) for each of its metrics and split cells."""

    def __init__(self, plan: AnalysisPlan, prep: Prepared, entry: PlanTest, tables: dict[str, list],
                 units: UnitSource | None = None, by_metric: dict[str, pd.DataFrame] | None = None) -> None:
        self.plan = plan
        self.units = units
        self.prep = prep
        self.by_metric = by_metric
        self.entry = entry
        self.spec = catalog.TESTS[catalog.ALIASES.get(entry.test, entry.test)]
        self.alpha = entry.alpha if entry.alpha is not None else plan.alpha
        self.tables = tables
        self.pooled_source = prep.frame["participant"].isna().all()
        # the last cell's Blocks (an omnibus, then its post-hoc pairs, read the same cell's blocks)
        self._blocks: tuple[pd.DataFrame, str, Blocks] | None = None

    # -- rows ------------------------------------------------------------------------------------
    def row(self, metric: str, split: str, **kw: Any) -> TestRow:
        return TestRow(
            test_id=self.entry.id,
            role=self.entry.role,
            kind=kw.pop("kind", "omnibus"),
            metric=metric,
            test=kw.pop("test", self.spec.name),
            compare=self.entry.compare,
            split=split,
            alpha=self.alpha,
            **kw,
        )

    def finding_row(
        self, metric: str, split: str, f: Finding, spec: TestSpec, notes: Sequence[str], **kw: Any
    ) -> TestRow:
        """The row of one finding: its summary's fields, the data ``notes`` then the test's warnings."""
        s = f.summary
        return self.row(
            metric,
            split,
            test=f.test or spec.name,
            **{name: getattr(s, name) for name in _SUMMARY_COLUMNS},
            p_adjust=f.p_adjust or s.p_adjust or "none",
            significant=f.significant,
            critical_value=f.critical_value,
            warnings=_join(notes, f.warnings),
            status=f.status,
            **kw,
        )

    def cell(
        self, levels: Sequence[str], sub: pd.DataFrame, options: dict[str, Any] | None = None, **data: Any
    ) -> Cell:
        es = self.entry.effect_size
        return Cell(
            levels=tuple(levels),
            alpha=self.alpha,
            options=dict(self.entry.options if options is None else options),
            effect_size=es[0] if es else None,
            reference=self.entry.reference,
            units=sub,
            compare=self.entry.compare,
            **data,
        )

    def parent_label(self, metric: str, split: str) -> str:
        return f"{self.entry.id}/{metric}" + (f"[{split}]" if split else "")

    def levels_for(self, factor: str, values: pd.Series) -> list[str]:
        return ordered_levels(values, self.plan.level_order(factor, self.entry))

    def pairs(self, levels: list[str]) -> list[tuple[str, str]]:
        if isinstance(self.entry.pairs, list):
            return [(a, b) for a, b in self.entry.pairs if a in levels and b in levels]
        return list(itertools.combinations(levels, 2))

    def metric_rows(self, metric: str) -> pd.DataFrame:
        """The prepared rows of ``metric`` (from the plan-wide split when the caller made one)."""
        frame = self.prep.frame
        if self.by_metric is None:
            return frame[frame["metric"] == metric]
        if metric not in self.by_metric:
            self.by_metric[metric] = frame[frame["metric"] == metric]
        return self.by_metric[metric]

    # -- main ------------------------------------------------------------------------------------
    def run(self) -> list[TestRow]:
        rows: list[TestRow] = []
        for metric in self.entry.metrics:
            data = self.metric_rows(metric)
            if data.empty:
                rows.append(self.row(metric, "", status="not_computed", warnings="no values for this metric"))
                continue
            try:
                rows.extend(self.run_metric(metric, data))
            except StudyctlError as exc:
                rows.append(self.row(metric, "", status="not_computed", warnings=str(exc)))
        rows = [_mark_undefined(r) for r in rows]
        primary = [i for i, r in enumerate(rows) if r.kind != "posthoc" and r.status == "ok" and np.isfinite(r.p)]
        if self.entry.correction != "none" and primary:
            adj = adjust_pvalues([rows[i].p for i in primary], self.entry.correction)
            for i, a in zip(primary, adj, strict=True):
                rows[i] = rows[i].with_(
                    p_adj=float(a),
                    p_adjust=self.entry.correction,
                    significant=bool(a < self.alpha) if rows[i].significant is not None else None,
                )
        return rows

    def run_metric(self, metric: str, data: pd.DataFrame) -> list[TestRow]:
        kind = self.plan.metric_kind(metric)
        compare_col = factor_column(self.entry.compare)
        by_cols = [factor_column(b) for b in self.entry.by]
        # A model's second factor (``options.factor``, e.g. group × condition) stays in the units too.
        extra = [factor_column(self.entry.options["factor"])] if "factor" in self.spec.options and \
            "factor" in self.entry.options else []
        keep = list(dict.fromkeys([compare_col, *by_cols, *extra]))
        design = self.spec.design
        if self.pooled_source and design in (catalog.BETWEEN, catalog.WITHIN):
            why = f"{self.spec.name} needs per-participant values; the data source has pooled counts"
            return [self.row(metric, "", status="not_computed", warnings=why)]
        if design == catalog.PROPORTION:
            units = pooled_counts(data, keep)
        else:
            units = (unit_values(data, kind=kind, keep=keep, aggregate=self.plan.aggregate) if self.units is None
                     else self.units(metric, kind, keep, self.plan.aggregate, data))
        rows: list[TestRow] = []
        split_levels = [self.levels_for(b, units[factor_column(b)]) for b in self.entry.by]
        for combo in itertools.product(*split_levels) if self.entry.by else [()]:
            sub = units
            for col, lv in zip(by_cols, combo, strict=True):
                sub = sub[sub[col] == lv]
            split = ", ".join(f"{b}={lv}" for b, lv in zip(self.entry.by, combo, strict=True))
            levels = self.levels_for(self.entry.compare, sub[compare_col])
            rows.extend(self.run_cell(metric, split, sub, compare_col, levels))
        return rows

    def run_cell(self, metric: str, split: str, sub: pd.DataFrame, col: str, levels: list[str]) -> list[TestRow]:
        spec = self.spec
        if spec.design == catalog.PROPORTION:
            return self.run_counts(metric, split, sub, col, levels)
        if spec.design == catalog.DESCRIPTIVE:
            values = [sub.loc[sub[col] == lv, "value"].to_numpy(dtype=float) for lv in levels]
            head = {"test_id": self.entry.id, "metric": metric, "split": split}
            assert spec.tabulate is not None, f"{spec.name}: a descriptive entry needs tabulate"
            rows = spec.tabulate(self.cell(levels, sub, samples=tuple(values)))
            self.tables[spec.table].extend({**head, **r} for r in rows)
            return []
        if len(levels) < spec.min_levels:
            why = (
                f"needs at least {spec.min_levels} levels of {self.entry.compare} with values, found "
                f"{len(levels)} ({', '.join(levels) or 'none'})"
            )
            return [self.row(metric, split, status="not_computed", groups=", ".join(levels), warnings=why)]
        if spec.each == EACH_PAIR:
            if len(levels) > 2 or self.entry.pairs is not None:
                pairs, kind = self.pairs(levels), "pairwise"
            else:
                pairs, kind = [(levels[0], levels[1])], "two_sample"
            return [r for a, b in pairs for r in self.run_pair(metric, split, sub, col, a, b, spec, kind=kind)]
        return self.run_omnibus(metric, split, sub, col, levels)

    # -- shaping ---------------------------------------------------------------------------------
    def samples(self, sub: pd.DataFrame, col: str, levels: list[str]) -> tuple[list[np.ndarray], list[str]]:
        """Independent samples: the finite values of each level, and notes on what was left out."""
        warnings = []
        out = []
        single = []
        column, values = sub[col].to_numpy(dtype=object), sub["value"].to_numpy(dtype=float)
        for lv in levels:
            vals = values[column == lv]
            nan = int(np.isnan(vals).sum())
            if nan:
                warnings.append(f"{lv}: {nan} undefined value(s) left out (e.g. no reports for a ratio)")
            vals = vals[~np.isnan(vals)]
            if len(vals) == 1:
                single.append(lv)
            out.append(vals)
        if single:
            warnings.append(f"only 1 value in {', '.join(single)}: the test has almost no power")
        return out, warnings

    def paired(self, sub: pd.DataFrame, col: str, levels: list[str]) -> tuple[np.ndarray, list[str]]:
        """A participants × levels matrix of complete blocks, and a note on who was left out."""
        if self._blocks is None or self._blocks[0] is not sub or self._blocks[1] != col:
            self._blocks = (sub, col, Blocks(sub, col))
        matrix, dropped = self._blocks[2].matrix(levels)
        warnings = []
        if dropped:
            warnings.append(
                f"{len(dropped)} participant(s) without values in every compared level left out of this "
                f"paired test: {', '.join(dropped[:8])}{' …' if len(dropped) > 8 else ''}"
            )
        return matrix, warnings

    # -- dispatch --------------------------------------------------------------------------------
    def run_pair(
        self,
        metric: str,
        split: str,
        sub: pd.DataFrame,
        col: str,
        a: str,
        b: str,
        spec: TestSpec,
        *,
        kind: str,
        parent: str = "",
        options: dict[str, Any] | None = None,
    ) -> list[TestRow]:
        """A two-sample test of levels ``a`` and ``b`` (independent or paired, as the test's design)."""
        common: dict[str, Any] = {"kind": kind, "test": spec.name, "groups": f"{a} vs {b}", "parent": parent}
        if spec.design == catalog.WITHIN:
            matrix, notes = self.paired(sub, col, [a, b])
            n = matrix.shape[0]
            common.update(n=n, n_per_group=f"{n} pairs")
            if n < 1:
                return [self.row(metric, split, status="not_computed", warnings="no participant has values in "
                                 "both levels", **common)]
            samples = (matrix[:, 0], matrix[:, 1])
        else:
            (x, y), notes = self.samples(sub, col, [a, b])
            common.update(n=len(x) + len(y), n_per_group=f"{len(x)}; {len(y)}")
            samples = (x, y)
        assert spec.run is not None
        try:
            # the cell's units as they are: a test that reads them keeps its two levels' rows (models' _long)
            (finding,) = spec.run(self.cell([a, b], sub, options, samples=samples))
        except StudyctlError as exc:
            return [self.row(metric, split, status="not_computed", warnings=str(exc), **common)]
        common.pop("test")
        return [self.finding_row(metric, split, finding, spec, notes, **common)]

    def run_omnibus(self, metric: str, split: str, sub: pd.DataFrame, col: str, levels: list[str]) -> list[TestRow]:
        """A test of every level at once; a pairwise procedure gives only its pairs."""
        spec = self.spec
        if spec.design == catalog.WITHIN:
            matrix, notes = self.paired(sub, col, levels)
            n = matrix.shape[0]
            base = {"groups": ", ".join(levels), "n": n, "n_per_group": f"{n} complete blocks × {len(levels)}"}
            if n < 2:
                why = f"needs at least 2 participants with values in every level, found {n}"
                return [self.row(metric, split, status="not_computed", warnings=_join(notes, [why]), **base)]
            samples = [matrix[:, j] for j in range(matrix.shape[1])]
        else:
            samples, notes = self.samples(sub, col, levels)
            n_per = "; ".join(str(len(s)) for s in samples)
            base = {"groups": ", ".join(levels), "n": int(sum(len(s) for s in samples)), "n_per_group": n_per}
            empty = [lv for lv, s in zip(levels, samples, strict=True) if len(s) == 0]
            if empty:
                return [self.row(metric, split, status="not_computed", warnings=f"no values for {', '.join(empty)}",
                                 **base)]
        cell = self.cell(levels, sub, samples=tuple(samples))
        if spec.pairwise:
            return self.run_procedure(metric, split, cell, spec, kind="pairwise")
        assert spec.run is not None
        try:
            findings = spec.run(cell)
        except StudyctlError as exc:
            return [self.row(metric, split, status="not_computed", warnings=_join(notes, [str(exc)]), **base)]
        if any(f.term for f in findings):  # a model: one row per term (factor or interaction)
            return [self.finding_row(metric, split, f, spec, notes, **{**base, "groups": f.term}) for f in findings]
        (finding,) = findings
        row = self.finding_row(metric, split, finding, spec, notes, **base)
        ph = self.entry.posthoc
        if ph is None:
            return [row]
        if ph.when == "significant" and not (row.p < self.alpha):
            note = f"post-hoc {ph.test} not run: p = {row.p:.3g} ≥ alpha"
            return [row.with_(warnings="; ".join(filter(None, [row.warnings, note])))]
        return [row, *self.run_posthoc(metric, split, sub, col, levels, cell, ph)]

    def run_posthoc(
        self, metric: str, split: str, sub: pd.DataFrame, col: str, levels: list[str], cell: Cell, ph: Posthoc
    ) -> list[TestRow]:
        """The entry's post-hoc test: a pairwise procedure on the cell, or a two-sample test of every pair
        with its p-values adjusted over the pairs."""
        name, variant = catalog.POSTHOC_VARIANTS.get(ph.test, (ph.test, ph.variant or "dunn"))
        spec = catalog.TESTS[name]
        if spec.pairwise:
            options = {**self.entry.options, "p_adjust": ph.p_adjust, "variant": variant}
            ph_cell = dataclasses.replace(cell, options=options)
            return self.run_procedure(metric, split, ph_cell, spec, kind="posthoc")
        parent = self.parent_label(metric, split)
        rows: list[TestRow] = []
        for a, b in itertools.combinations(levels, 2):
            rows.extend(self.run_pair(metric, split, sub, col, a, b, spec, kind="posthoc", parent=parent, options={}))
        ok = [i for i, r in enumerate(rows) if r.status == "ok"]
        adj = adjust_pvalues([rows[i].p for i in ok], ph.p_adjust)
        for i, a_ in zip(ok, adj, strict=True):
            rows[i] = rows[i].with_(p_adj=float(a_), p_adjust=ph.p_adjust, significant=bool(a_ < self.alpha))
        return rows

    def run_procedure(self, metric: str, split: str, cell: Cell, spec: TestSpec, *, kind: str) -> list[TestRow]:
        """A pairwise procedure on one cell: a row per pair (its own adjusted p-values)."""
        parent = self.parent_label(metric, split)
        assert spec.run is not None
        try:
            findings = spec.run(cell)
        except StudyctlError as exc:
            return [self.row(metric, split, kind=kind, test=spec.name, status="not_computed", warnings=str(exc),
                             parent=parent)]
        out = []
        for f in findings:
            assert f.pair is not None, f"{spec.name}: a pairwise procedure's findings name their pair"
            i, j = f.pair
            ni, nj = len(cell.samples[i]), len(cell.samples[j])
            groups = f"{cell.levels[i]} vs {cell.levels[j]}"
            out.append(self.finding_row(metric, split, f, spec, (), kind=kind, groups=groups, n=ni + nj,
                                        n_per_group=f"{ni}; {nj}", parent=parent))
        return out

    def run_counts(self, metric: str, split: str, sub: pd.DataFrame, col: str, levels: list[str]) -> list[TestRow]:
        """Pooled proportions: a test of each level (an interval) or of each pair of levels."""
        spec = self.spec
        assert spec.run is not None
        counts = {
            lv: (int(sub.loc[sub[col] == lv, "successes"].sum()), int(sub.loc[sub[col] == lv, "chances"].sum()))
            for lv in levels
        }
        out: list[TestRow] = []
        if spec.each == EACH_LEVEL:
            for lv in levels:
                x, n = counts[lv]
                try:
                    (f,) = spec.run(self.cell([lv], sub[sub[col] == lv], counts=((x, n),)))
                    out.append(self.finding_row(metric, split, f, spec, (), kind="interval", groups=lv, n=n,
                                                n_per_group=f"{x}/{n}"))
                except StudyctlError as exc:
                    out.append(self.row(metric, split, kind="interval", groups=lv, n=n, status="not_computed",
                                        warnings=str(exc)))
            return out
        if len(levels) < 2:
            return [self.row(metric, split, status="not_computed", groups=", ".join(levels),
                             warnings="needs two levels with counts")]
        for a, b in self.pairs(levels):
            (x1, n1), (x2, n2) = counts[a], counts[b]
            try:
                (f,) = spec.run(self.cell([a, b], sub[sub[col].isin([a, b])], counts=((x1, n1), (x2, n2))))
                out.append(self.finding_row(metric, split, f, spec, (), kind="pairwise", groups=f"{a} vs {b}",
                                            n=n1 + n2, n_per_group=f"{x1}/{n1}; {x2}/{n2}"))
            except StudyctlError as exc:
                out.append(self.row(metric, split, kind="pairwise", groups=f"{a} vs {b}", status="not_computed",
                                    warnings=str(exc)))
        return out


def _mark_undefined(row: TestRow) -> TestRow:
    """A test whose statistic and p-value are both undefined (degenerate data) is not a result: say so."""
    if row.status != "ok" or row.kind in ("interval", "descriptive") or row.test == "newcombe":
        return row
    if np.isfinite(row.p) or np.isfinite(row.p_adj) or np.isfinite(row.statistic):
        return row
    why = "undefined for these data (e.g. one value per level or no variation)"
    return row.with_(
        status="not_computed", significant=None, warnings="; ".join(filter(None, [row.warnings, f"the test is {why}"]))
    )


def hypothesis_rows(plan: AnalysisPlan, prep: Prepared, *, units: UnitSource | None = None) -> tuple[TestRow, ...]:
    """The rows of the plan's hypothesis-test entries (:func:`is_hypothesis_entry`) on prepared data, and nothing
    else: no descriptive or interval entries, no result tables. What a power analysis counts; each row is the
    row :func:`run_plan` gives for that entry (the same runner), ``units`` only says where unit values come from.
    """
    tables: dict[str, list] = {"percent_change": [], "descriptives": [], "likert": []}
    rows: list[TestRow] = []
    by_metric: dict[str, pd.DataFrame] = {}  # each metric's rows filtered once, not once per entry
    for entry in plan.tests:
        if is_hypothesis_entry(entry):
            rows.extend(_EntryRunner(plan, prep, entry, tables, units, by_metric).run())
    return tuple(rows)


def run_plan(plan: AnalysisPlan, table: MetricTable, *, on_step: Callable[[str], None] | None = None) -> AnalysisResult:
    """Execute every test of ``plan`` on ``table``.

    Parameters
    ----------
    plan
        A validated plan (:func:`studyctl.analysis.plan.load_plan`).
    table
        The metric values (:func:`studyctl.analysis.metrics.compute_metrics` or
        :func:`studyctl.analysis.table.read_summary_csv`).
    on_step
        Called with each test id before it runs (progress display).

    Returns
    -------
    AnalysisResult
        With ``partial`` set when anything could not be computed; nothing is dropped silently.
    """
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    prep = prepare(plan, table)
    timings["prepare_s"] = time.perf_counter() - t0
    tables: dict[str, list] = {"percent_change": [], "descriptives": [], "likert": []}
    rows: list[TestRow] = []
    for entry in plan.tests:
        if on_step is not None:
            on_step(entry.id)
        t1 = time.perf_counter()
        rows.extend(_EntryRunner(plan, prep, entry, tables).run())
        timings[f"test:{entry.id}_s"] = time.perf_counter() - t1
    units = units_table(plan, prep)
    frames = {name: pd.DataFrame(rows_) for name, rows_ in tables.items() if rows_}
    frames["units"] = units
    frames["cells"] = cells_table(plan, units) if not units.empty else pd.DataFrame()
    frames["proportions"] = proportions_table(plan, prep)
    problems = list(prep.problems)
    for r in rows:
        if r.status != "ok":
            problems.append(
                f"{r.test_id}/{r.metric}{f' [{r.split}]' if r.split else ''} {r.groups}: not computed: {r.warnings}"
            )
    timings["total_s"] = time.perf_counter() - t0
    if prep.notes:
        frames["notes"] = pd.DataFrame({"note": list(prep.notes)})
    return AnalysisResult(
        plan=plan,
        data=table,
        rows=tuple(rows),
        tables=frames,
        missing=prep.missing,
        problems=tuple(problems),
        timings=timings,
    )
