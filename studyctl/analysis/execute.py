"""Run an analysis plan's tests on a metric table and collect one tidy row per test.

A test that cannot be computed (too few values, a constant sample, pooled counts where per-participant
values are needed) still gets its row, with ``status = "not_computed"`` and the reason in ``warnings``,
so a partial result is visibly partial.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pandas as pd

from studyctl import stats
from studyctl.analysis import catalog
from studyctl.analysis.plan import AnalysisPlan, PlanTest, Posthoc
from studyctl.analysis.results import AnalysisResult, TestRow
from studyctl.analysis.shape import Prepared, factor_column, ordered_levels, prepare, unit_values
from studyctl.analysis.table import MetricTable
from studyctl.errors import StatsInputError, StudyctlError

NAN = math.nan


def _get(result: Any, *names: str, default: float = NAN) -> Any:
    """First attribute of ``result`` among ``names`` that exists (stats result field names)."""
    for name in names:
        if hasattr(result, name):
            value = getattr(result, name)
            if value is not None:
                return value
    return default


def _f(x: Any) -> float:
    try:
        return float(x)
    except (TypeError, ValueError):
        return NAN


def _result_warnings(result: Any) -> list[str]:
    out: list[str] = []
    for name in ("warnings", "flags", "notes"):
        value = getattr(result, name, None)
        if isinstance(value, str) and value:
            out.append(value)
        elif isinstance(value, list | tuple):
            out.extend(str(v) for v in value if v)
    return out


def p_adjust(pvalues: Sequence[float], method: str) -> np.ndarray:
    """Holm, Bonferroni or Benjamini-Hochberg adjusted p-values (NaN entries stay NaN and are not counted)."""
    p = np.asarray(pvalues, dtype=float)
    out = np.full_like(p, np.nan)
    ok = np.isfinite(p)
    m = int(ok.sum())
    if m == 0 or method == "none":
        return p.copy()
    q = p[ok]
    order = np.argsort(q, kind="stable")
    ranked = q[order]
    if method == "bonferroni":
        adj = np.minimum(q * m, 1.0)
    elif method == "holm":
        steps = np.maximum.accumulate(ranked * (m - np.arange(m)))
        adj = np.empty(m)
        adj[order] = np.minimum(steps, 1.0)
    elif method == "bh":
        steps = ranked * m / np.arange(1, m + 1)
        steps = np.minimum.accumulate(steps[::-1])[::-1]
        adj = np.empty(m)
        adj[order] = np.minimum(steps, 1.0)
    else:
        raise ValueError(f"unknown p adjustment {method!r}")
    out[ok] = adj
    return out


class _EntryRunner:
    """Runs one plan entry (one test family) for each of its metrics and split cells."""

    def __init__(self, plan: AnalysisPlan, prep: Prepared, entry: PlanTest, tables: dict[str, list]) -> None:
        self.plan = plan
        self.prep = prep
        self.entry = entry
        self.name = catalog.ALIASES.get(entry.test, entry.test)
        self.spec = catalog.TESTS[self.name]
        self.alpha = entry.alpha if entry.alpha is not None else plan.alpha
        self.tables = tables
        self.pooled_source = prep.frame["participant"].isna().all()

    # -- helpers ---------------------------------------------------------------------------------
    def row(self, metric: str, split: str, **kw: Any) -> TestRow:
        return TestRow(
            test_id=self.entry.id,
            role=self.entry.role,
            kind=kw.pop("kind", "omnibus"),
            metric=metric,
            test=kw.pop("test", self.name),
            compare=self.entry.compare,
            split=split,
            alpha=self.alpha,
            **kw,
        )

    def result_row(self, metric: str, split: str, res: Any, warns: list[str], *, p: float, **kw: Any) -> TestRow:
        """A computed row: significant when ``p`` < alpha (unless given), our warnings then the result's."""
        kw.setdefault("significant", bool(p < self.alpha))
        return self.row(metric, split, p=p, warnings="; ".join(warns + _result_warnings(res)), **kw)

    def not_computed(self, metric: str, split: str, warns: list[str], why: str, base: dict) -> list[TestRow]:
        """The single not-computed row of an omnibus test, saying why after the data warnings."""
        return [self.row(metric, split, status="not_computed", warnings="; ".join([*warns, why]), **base)]

    def with_posthoc(self, row: TestRow, posthoc: Callable[[Posthoc], list[TestRow]]) -> list[TestRow]:
        """The omnibus row and the rows of the entry's post-hoc test, if any.

        With ``when: significant`` and an omnibus p not below alpha, only the row, noting why the post-hoc
        test did not run.
        """
        ph = self.entry.posthoc
        if ph is None:
            return [row]
        if ph.when == "significant" and not (row.p < self.alpha):
            return [self._posthoc_skipped(row, ph.test)]
        return [row, *posthoc(ph)]

    def levels_for(self, factor: str, values: pd.Series, metric: str) -> list[str]:
        if factor == self.entry.compare and self.entry.levels:
            preferred = self.entry.levels
        elif factor == "condition":
            preferred = self.plan.condition_ids
        elif factor == "group":
            preferred = self.plan.group_ids or None
        else:
            preferred = None
        return ordered_levels(values, preferred)

    # -- main ------------------------------------------------------------------------------------
    def run(self) -> list[TestRow]:
        rows: list[TestRow] = []
        for metric in self.entry.metrics:
            data = self.prep.frame[self.prep.frame["metric"] == metric]
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
            adj = p_adjust([rows[i].p for i in primary], self.entry.correction)
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
        keep = list(dict.fromkeys([compare_col, *by_cols]))
        design = self.spec.design
        if self.pooled_source and design in (catalog.BETWEEN, catalog.WITHIN):
            return [
                self.row(
                    metric,
                    "",
                    status="not_computed",
                    warnings=f"{self.name} needs per-participant values; the data source has pooled counts",
                )
            ]
        if design == catalog.PROPORTION:
            units = self._pooled_counts(data, keep)
        else:
            units = unit_values(data, kind=kind, keep=keep, aggregate=self.plan.aggregate)
        rows: list[TestRow] = []
        split_levels = [self.levels_for(b, units[factor_column(b)], metric) for b in self.entry.by]
        for combo in itertools.product(*split_levels) if self.entry.by else [()]:
            sub = units
            for col, lv in zip(by_cols, combo, strict=True):
                sub = sub[sub[col] == lv]
            split = ", ".join(f"{b}={lv}" for b, lv in zip(self.entry.by, combo, strict=True))
            levels = self.levels_for(self.entry.compare, sub[compare_col], metric)
            rows.extend(self.run_cell(metric, kind, split, sub, compare_col, levels))
        return rows

    def _pooled_counts(self, data: pd.DataFrame, keep: list[str]) -> pd.DataFrame:
        g = data.groupby(keep, dropna=False, sort=False)
        out = g.agg(
            successes=("value", "sum"), chances=("denominator", "sum"), participants=("participant", "nunique")
        ).reset_index()
        return out

    def run_cell(
        self, metric: str, kind: str, split: str, sub: pd.DataFrame, col: str, levels: list[str]
    ) -> list[TestRow]:
        design = self.spec.design
        if design == catalog.PROPORTION:
            return self.run_proportion(metric, split, sub, col, levels)
        if design == catalog.DESCRIPTIVE:
            self.run_descriptive(metric, kind, split, sub, col, levels)
            return []
        if len(levels) < self.spec.min_levels:
            return [
                self.row(
                    metric,
                    split,
                    status="not_computed",
                    groups=", ".join(levels),
                    warnings=f"needs at least {self.spec.min_levels} levels of {self.entry.compare} with "
                    f"values, found {len(levels)} ({', '.join(levels) or 'none'})",
                )
            ]
        if self.spec.max_levels == 2 and (len(levels) > 2 or self.entry.pairs is not None):
            pairs = self.pairs(levels)
            out = []
            for a, b in pairs:
                out.extend(self.run_two(metric, split, sub, col, a, b, kind="pairwise"))
            return out
        if self.spec.max_levels == 2:
            return self.run_two(metric, split, sub, col, levels[0], levels[1], kind="two_sample")
        if design == catalog.WITHIN:
            return self.run_within(metric, split, sub, col, levels)
        return self.run_between(metric, split, sub, col, levels)

    def pairs(self, levels: list[str]) -> list[tuple[str, str]]:
        if isinstance(self.entry.pairs, list):
            return [(a, b) for a, b in self.entry.pairs if a in levels and b in levels]
        return list(itertools.combinations(levels, 2))

    # -- samples ---------------------------------------------------------------------------------
    def samples(self, sub: pd.DataFrame, col: str, levels: list[str]) -> tuple[list[np.ndarray], list[str]]:
        warnings = []
        out = []
        single = []
        for lv in levels:
            vals = sub.loc[sub[col] == lv, "value"].to_numpy(dtype=float)
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

    def paired(self, sub: pd.DataFrame, col: str, levels: list[str]) -> tuple[np.ndarray, list[str], list[str]]:
        """A participants × levels matrix of complete blocks, and who was left out."""
        wide = sub.pivot_table(index="participant", columns=col, values="value", aggfunc="mean")
        wide = wide.reindex(columns=levels)
        complete = wide.dropna()
        dropped = [str(p) for p in wide.index.difference(complete.index)]
        warnings = []
        if dropped:
            warnings.append(
                f"{len(dropped)} participant(s) without values in every compared level left out of this "
                f"paired test: {', '.join(dropped[:8])}{' …' if len(dropped) > 8 else ''}"
            )
        return complete.to_numpy(dtype=float), warnings, dropped

    # -- tests -----------------------------------------------------------------------------------
    def run_two(
        self,
        metric: str,
        split: str,
        sub: pd.DataFrame,
        col: str,
        a: str,
        b: str,
        *,
        kind: str,
        parent: str = "",
        test: str | None = None,
        options: dict | None = None,
    ) -> list[TestRow]:
        test = test or self.name
        opts = dict(self.entry.options if options is None else options)
        critical = bool(opts.pop("critical_value", False))
        label = f"{a} vs {b}"
        common: dict[str, Any] = {"kind": kind, "test": test, "groups": label, "parent": parent}
        try:
            if test == "signed_rank":
                matrix, warns, _ = self.paired(sub, col, [a, b])
                n = matrix.shape[0]
                common.update(n=n, n_per_group=f"{n} pairs")
                if n < 1:
                    raise StatsInputError("no participant has values in both levels")
                res = stats.signed_rank(matrix[:, 0], matrix[:, 1], **opts)
                n_r = int(_get(res, "n_used", "n_nonzero", "n", default=n))
                w_min = _f(_get(res, "w_min"))
                row = self._rank_row(metric, split, res, "V (R+)", "matched_pairs_r", [], common)
                if critical:
                    crit = stats.signed_rank_critical(n_r, alpha=self.alpha)
                    crit_v = NAN if crit is None else float(crit)
                    sig = None if crit is None else bool(w_min <= crit)
                    if crit is None:
                        warns.append(f"no exact critical value exists for n_r = {n_r} at alpha {self.alpha}")
                    row = row.with_(
                        statistic_name="W = min(R+, R-)",
                        statistic=w_min,
                        critical_value=crit_v,
                        significant=sig,
                        df=float(n_r),
                        method=f"{row.method}; decision W <= W_critical (n_r = {n_r} non-zero pairs)",
                    )
                return [row.with_(warnings="; ".join(warns + _result_warnings(res)))]
            samples, warns = self.samples(sub, col, [a, b])
            x, y = samples
            common.update(n=len(x) + len(y), n_per_group=f"{len(x)}; {len(y)}")
            if test == "rank_sum":
                res = stats.rank_sum(x, y, **opts)
                return [self._rank_row(metric, split, res, "U", "rank_biserial", warns, common)]
            raise StatsInputError(f"{test} is not a two-sample test")
        except StudyctlError as exc:
            return [self.row(metric, split, status="not_computed", warnings=str(exc), **common)]

    def run_between(self, metric: str, split: str, sub: pd.DataFrame, col: str, levels: list[str]) -> list[TestRow]:
        samples, warns = self.samples(sub, col, levels)
        n_per = "; ".join(str(len(s)) for s in samples)
        base = {"groups": ", ".join(levels), "n": int(sum(len(s) for s in samples)), "n_per_group": n_per}
        empty = [lv for lv, s in zip(levels, samples, strict=True) if len(s) == 0]
        if empty:
            return [
                self.row(metric, split, status="not_computed", warnings=f"no values for {', '.join(empty)}", **base)
            ]
        try:
            if self.name == "kruskal_wallis":
                res = stats.kruskal_wallis(*samples)
                row = self.result_row(
                    metric,
                    split,
                    res,
                    warns,
                    statistic_name="H",
                    statistic=_f(res.statistic),
                    df=_f(_get(res, "df")),
                    p=_f(res.pvalue),
                    method="Kruskal-Wallis, chi-squared approximation, tie-corrected",
                    effect_size_name="epsilon_squared",
                    effect_size=_f(_get(res, "epsilon_squared", "effect_size")),
                    **base,
                )
            elif self.name == "anova_oneway":
                res = stats.anova_oneway(*samples)
                es_name = (self.entry.effect_size or ["eta_squared"])[0]
                row = self.result_row(
                    metric,
                    split,
                    res,
                    warns,
                    statistic_name="F",
                    statistic=_f(res.statistic),
                    df=_f(_get(res, "df_between")),
                    p=_f(res.pvalue),
                    method=f"one-way ANOVA F({_f(_get(res, 'df_between')):g}, {_f(_get(res, 'df_within')):g})",
                    effect_size_name=es_name,
                    effect_size=_f(_get(res, es_name, "eta_squared")),
                    **base,
                )
            elif self.name in ("tukey_hsd", "dunn"):
                row = self.row(metric, split, kind="omnibus", statistic_name="", method="pairwise only", **base)
                return self.pairwise(
                    metric,
                    split,
                    samples,
                    levels,
                    self.name,
                    row,
                    kind="pairwise",
                    p_adjust_method=str(self.entry.options.get("p_adjust", "holm")),
                    variant=str(self.entry.options.get("variant", "dunn")),
                )
            else:
                raise StatsInputError(f"{self.name} is not a between-subject omnibus test")
        except StudyctlError as exc:
            return self.not_computed(metric, split, warns, str(exc), base)

        def posthoc(ph: Posthoc) -> list[TestRow]:
            if ph.test == "rank_sum":
                return self._pairs_posthoc(metric, split, sub, col, levels, "rank_sum", ph.p_adjust)
            test = "dunn" if ph.test in ("dunn", "multcompare") else ph.test
            variant = "multcompare" if ph.test == "multcompare" else (ph.variant or "dunn")
            return self.pairwise(
                metric, split, samples, levels, test, row, kind="posthoc", p_adjust_method=ph.p_adjust, variant=variant
            )

        return self.with_posthoc(row, posthoc)

    def _rank_row(
        self, metric: str, split: str, res: Any, stat_name: str, es_name: str, warns: list[str], common: dict
    ) -> TestRow:
        """The row of a rank-sum or signed-rank result."""
        return self.result_row(
            metric,
            split,
            res,
            warns,
            statistic_name=stat_name,
            statistic=_f(res.statistic),
            z=_f(_get(res, "z")),
            p=_f(res.pvalue),
            method=str(_get(res, "method", default="")),
            effect_size_name=es_name,
            effect_size=_f(_get(res, "effect_size")),
            **common,
        )

    def _posthoc_skipped(self, row: TestRow, test: str) -> TestRow:
        note = f"post-hoc {test} not run: p = {row.p:.3g} ≥ alpha"
        return row.with_(warnings="; ".join(filter(None, [row.warnings, note])))

    def _pairs_posthoc(
        self, metric: str, split: str, sub: pd.DataFrame, col: str, levels: list[str], test: str, adjust: str
    ) -> list[TestRow]:
        """Every pair of levels with a two-sample test, p-values adjusted over the pairs."""
        rows: list[TestRow] = []
        parent = self.parent_label(metric, split)
        for a, b in itertools.combinations(levels, 2):
            rows.extend(
                self.run_two(metric, split, sub, col, a, b, kind="posthoc", parent=parent, test=test, options={})
            )
        return self._adjust_posthoc(rows, adjust)

    def parent_label(self, metric: str, split: str) -> str:
        return f"{self.entry.id}/{metric}" + (f"[{split}]" if split else "")

    def _adjust_posthoc(self, rows: list[TestRow], method: str) -> list[TestRow]:
        idx = [i for i, r in enumerate(rows) if r.status == "ok"]
        adj = p_adjust([rows[i].p for i in idx], method)
        for i, a in zip(idx, adj, strict=True):
            rows[i] = rows[i].with_(p_adj=float(a), p_adjust=method, significant=bool(a < self.alpha))
        return rows

    def pairwise(
        self,
        metric: str,
        split: str,
        samples: list[np.ndarray],
        levels: list[str],
        test: str,
        parent_row: TestRow,
        *,
        kind: str,
        p_adjust_method: str,
        variant: str,
    ) -> list[TestRow]:
        parent = self.parent_label(metric, split)
        out: list[TestRow] = [parent_row] if kind == "pairwise" and parent_row.statistic_name else []
        try:
            if test == "tukey_hsd":
                conf = float(self.entry.options.get("confidence", 0.95))
                res = stats.tukey_hsd(*samples, confidence=conf, names=levels)
                frame = res.to_frame()
                for _, r in frame.iterrows():
                    i, j = _pair_index(r, levels)
                    out.append(
                        self.row(
                            metric,
                            split,
                            kind=kind,
                            test="tukey_hsd",
                            groups=f"{levels[i]} vs {levels[j]}",
                            n=len(samples[i]) + len(samples[j]),
                            n_per_group=f"{len(samples[i])}; {len(samples[j])}",
                            statistic_name="diff (second − first)",
                            statistic=_f(r["diff"]),
                            p=NAN,
                            p_adj=_f(r["p_adj"]),
                            p_adjust="tukey",
                            significant=bool(_f(r["p_adj"]) < self.alpha),
                            effect_size_name="mean_difference",
                            effect_size=_f(r["diff"]),
                            estimate=_f(r["diff"]),
                            ci_low=_f(r["lower"]),
                            ci_high=_f(r["upper"]),
                            ci_level=conf,
                            method="Tukey HSD (Tukey-Kramer), studentized range",
                            parent=parent,
                        )
                    )
            elif test == "dunn":
                # MATLAB multcompare after kruskalwallis: the studentized range on mean ranks (df = inf).
                adjust = "tukey-kramer" if variant == "multcompare" else p_adjust_method
                res = stats.dunn(*samples, p_adjust=adjust, names=levels)
                frame = res.to_frame()
                for _, r in frame.iterrows():
                    i, j = _pair_index(r, levels)
                    p_raw = _f(r.get("p", r.get("pvalue", NAN)))
                    p_adj_v = _f(r.get("p_adj", p_raw))
                    method = (
                        "MATLAB multcompare after kruskalwallis (mean ranks, studentized range, df = inf)"
                        if variant == "multcompare"
                        else f"Dunn z test, two-sided, {p_adjust_method} adjusted"
                    )
                    out.append(
                        self.row(
                            metric,
                            split,
                            kind=kind,
                            test="dunn" if variant == "dunn" else "multcompare",
                            groups=f"{levels[i]} vs {levels[j]}",
                            n=len(samples[i]) + len(samples[j]),
                            n_per_group=f"{len(samples[i])}; {len(samples[j])}",
                            statistic_name="z",
                            statistic=_f(r.get("z", NAN)),
                            z=_f(r.get("z", NAN)),
                            p=p_raw,
                            p_adj=p_adj_v,
                            p_adjust="multcompare" if variant == "multcompare" else p_adjust_method,
                            significant=bool(p_adj_v < self.alpha),
                            effect_size_name="mean_rank_difference",
                            effect_size=_f(r.get("mean_rank_diff", r.get("diff", NAN))),
                            method=method,
                            parent=parent,
                        )
                    )
            else:
                raise StatsInputError(f"unknown pairwise procedure {test!r}")
        except StudyctlError as exc:
            out.append(
                self.row(metric, split, kind=kind, test=test, status="not_computed", warnings=str(exc), parent=parent)
            )
        return out

    def run_within(self, metric: str, split: str, sub: pd.DataFrame, col: str, levels: list[str]) -> list[TestRow]:
        matrix, warns, _dropped = self.paired(sub, col, levels)
        n = matrix.shape[0]
        base = {"groups": ", ".join(levels), "n": n, "n_per_group": f"{n} complete blocks × {len(levels)}"}
        if n < 2:
            why = f"needs at least 2 participants with values in every level, found {n}"
            return self.not_computed(metric, split, warns, why, base)
        try:
            if self.name == "friedman":
                res = stats.friedman(*[matrix[:, j] for j in range(matrix.shape[1])])
                chi2 = _f(res.statistic)
                k = len(levels)
                kendall = _f(_get(res, "kendall_w", "effect_size", default=chi2 / (n * (k - 1))))
                row = self.result_row(
                    metric,
                    split,
                    res,
                    warns,
                    statistic_name="chi2 (Friedman)",
                    statistic=chi2,
                    df=_f(_get(res, "df")),
                    p=_f(res.pvalue),
                    method=str(_get(res, "method", default="Friedman, chi-squared approximation, tie-corrected")),
                    effect_size_name="kendall_w",
                    effect_size=kendall,
                    **base,
                )
            elif self.name == "rm_anova":
                res = stats.rm_anova(*[matrix[:, j] for j in range(matrix.shape[1])])
                eps, p_gg = _f(_get(res, "epsilon_gg")), _f(_get(res, "pvalue_gg"))
                row = self.result_row(
                    metric,
                    split,
                    res,
                    warns,
                    statistic_name="F",
                    statistic=_f(res.statistic),
                    df=_f(_get(res, "df_effect")),
                    p=p_gg,
                    method=f"repeated-measures ANOVA F({_f(_get(res, 'df_effect')):g}, "
                    f"{_f(_get(res, 'df_error')):g}), participants as blocks; p with the Greenhouse-Geisser "
                    f"correction (epsilon = {eps:.3f}; uncorrected p = {_f(res.pvalue):.3g})",
                    effect_size_name="partial_eta_squared",
                    effect_size=_f(_get(res, "partial_eta_squared")),
                    significant=bool(p_gg < self.alpha) if np.isfinite(p_gg) else None,
                    **base,
                )
            else:
                raise StatsInputError(f"{self.name} is not a within-subject omnibus test")
        except StudyctlError as exc:
            return self.not_computed(metric, split, warns, str(exc), base)
        return self.with_posthoc(
            row, lambda ph: self._pairs_posthoc(metric, split, sub, col, levels, "signed_rank", ph.p_adjust)
        )

    def run_proportion(self, metric: str, split: str, sub: pd.DataFrame, col: str, levels: list[str]) -> list[TestRow]:
        conf = float(self.entry.options.get("confidence", 0.95))
        counts = {
            lv: (int(sub.loc[sub[col] == lv, "successes"].sum()), int(sub.loc[sub[col] == lv, "chances"].sum()))
            for lv in levels
        }
        out: list[TestRow] = []
        if self.name == "wilson":
            for lv in levels:
                x, n = counts[lv]
                try:
                    res = stats.wilson_interval(x, n, confidence=conf)
                    warn = "no chances (n = 0): interval undefined" if n == 0 else ""
                    out.append(
                        self.row(
                            metric,
                            split,
                            kind="interval",
                            groups=lv,
                            n=n,
                            n_per_group=f"{x}/{n}",
                            statistic_name="successes",
                            statistic=float(x),
                            estimate=_f(res.estimate),
                            ci_low=_f(res.lower),
                            ci_high=_f(res.upper),
                            ci_level=conf,
                            method="Wilson score interval",
                            warnings=warn,
                            status="ok" if n else "not_computed",
                        )
                    )
                except StudyctlError as exc:
                    out.append(
                        self.row(
                            metric, split, kind="interval", groups=lv, n=n, status="not_computed", warnings=str(exc)
                        )
                    )
            return out
        # newcombe over pairs
        if len(levels) < 2:
            return [
                self.row(
                    metric,
                    split,
                    status="not_computed",
                    groups=", ".join(levels),
                    warnings="needs two levels with counts",
                )
            ]
        for a, b in self.pairs(levels):
            (x1, n1), (x2, n2) = counts[a], counts[b]
            try:
                res = stats.newcombe_interval(x1, n1, x2, n2, confidence=conf)
                d, lo, hi = _f(res.difference), _f(res.lower), _f(res.upper)
                # The margin on the side of the difference towards zero (the papers' "CI" column): a pair
                # differs when |Δp| exceeds it, i.e. when the interval excludes 0.
                margin = _f(_get(res, "margin", default=d - lo if d > 0 else (hi - d if d < 0 else NAN)))
                sig = bool(abs(d) > margin) if d != 0 else False
                warn = "equal proportions: no margin towards zero (the paper prints NULL)" if d == 0 else ""
                out.append(
                    self.row(
                        metric,
                        split,
                        kind="pairwise",
                        groups=f"{a} vs {b}",
                        n=n1 + n2,
                        n_per_group=f"{x1}/{n1}; {x2}/{n2}",
                        statistic_name="margin (CI towards 0)",
                        statistic=margin,
                        estimate=d,
                        ci_low=lo,
                        ci_high=hi,
                        ci_level=conf,
                        effect_size_name="difference",
                        effect_size=d,
                        significant=sig,
                        method="Newcombe hybrid score (method 10); significant when |Δp| > margin",
                        warnings=warn,
                    )
                )
            except StudyctlError as exc:
                out.append(
                    self.row(
                        metric, split, kind="pairwise", groups=f"{a} vs {b}", status="not_computed", warnings=str(exc)
                    )
                )
        return out

    def run_descriptive(
        self, metric: str, kind: str, split: str, sub: pd.DataFrame, col: str, levels: list[str]
    ) -> None:
        if self.name == "percent_change":
            ref = self.entry.reference
            means = {
                lv: float(np.nanmean(sub.loc[sub[col] == lv, "value"])) if (sub[col] == lv).any() else NAN
                for lv in levels
            }
            ref_mean = means.get(ref, NAN)
            for lv in levels:
                pct = 100.0 * (means[lv] - ref_mean) / ref_mean if ref_mean not in (0.0,) else NAN
                self.tables["percent_change"].append(
                    {
                        "test_id": self.entry.id,
                        "metric": metric,
                        "split": split,
                        "level": lv,
                        "reference": ref,
                        "mean": means[lv],
                        "reference_mean": ref_mean,
                        "percent_change": pct,
                        "n": int((sub[col] == lv).sum()),
                    }
                )
        elif self.name == "descriptive":
            for lv in levels:
                vals = sub.loc[sub[col] == lv, "value"].to_numpy(dtype=float)
                self.tables["descriptives"].append(
                    {"test_id": self.entry.id, "metric": metric, "split": split, "level": lv, **describe(vals)}
                )
        elif self.name == "likert_table":
            for lv in levels:
                vals = sub.loc[sub[col] == lv, "value"].to_numpy(dtype=float)
                self.tables["likert"].append(
                    {"test_id": self.entry.id, "metric": metric, "split": split, "level": lv, **describe(vals)}
                )


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


def _pair_index(r: pd.Series, levels: list[str]) -> tuple[int, int]:
    """Indices of the two groups of a pairwise row: level names, else R-style 1-based group numbers."""
    out = []
    for key in ("group1", "group2"):
        v = r[key]
        if isinstance(v, str) and v in levels:
            out.append(levels.index(v))
            continue
        try:
            iv = int(v)
        except (TypeError, ValueError):
            raise StatsInputError(f"pairwise result names an unknown group {v!r}") from None
        if not 1 <= iv <= len(levels):
            raise StatsInputError(f"pairwise result group number {iv} is outside 1..{len(levels)}")
        out.append(iv - 1)
    return out[0], out[1]


def describe(vals: np.ndarray) -> dict[str, float]:
    """n, mean, SD, SE, median, quartiles, min and max of the finite values."""
    v = vals[np.isfinite(vals)]
    n = len(v)
    if n == 0:
        return {"n": 0, "mean": NAN, "sd": NAN, "se": NAN, "median": NAN, "q1": NAN, "q3": NAN, "min": NAN, "max": NAN}
    sd = float(np.std(v, ddof=1)) if n > 1 else NAN
    return {
        "n": n,
        "mean": float(v.mean()),
        "sd": sd,
        "se": sd / math.sqrt(n) if n > 1 else NAN,
        "median": float(np.median(v)),
        "q1": float(np.quantile(v, 0.25)),
        "q3": float(np.quantile(v, 0.75)),
        "min": float(v.min()),
        "max": float(v.max()),
    }


def _units_table(plan: AnalysisPlan, prep: Prepared) -> pd.DataFrame:
    """Per participant × condition (× level) values of every metric: what box plots and cells show."""
    parts = []
    for metric in plan.metrics:
        data = prep.frame[prep.frame["metric"] == metric]
        if data.empty:
            continue
        kind = plan.metric_kind(metric)
        keep = ["group", "condition"] + (["level"] if plan.metric_level(metric) else [])
        units = unit_values(
            data, kind=kind, keep=keep, aggregate="mean" if plan.aggregate == "none" else plan.aggregate
        )
        if "level" not in units:
            units["level"] = None
        parts.append(units.assign(metric=metric))
    cols = ["metric", "participant", "group", "condition", "level", "value", "successes", "chances", "n_trials"]
    if not parts:
        return pd.DataFrame(columns=cols)
    return pd.concat(parts, ignore_index=True).reindex(columns=cols)


def _cells_table(plan: AnalysisPlan, units: pd.DataFrame) -> pd.DataFrame:
    rows = []
    for (metric, cond, group, level), sel in units.groupby(
        ["metric", "condition", "group", "level"], dropna=False, sort=False
    ):
        vals = sel["value"].to_numpy(dtype=float)
        successes = float(sel["successes"].sum()) if sel["successes"].notna().any() else NAN
        chances = float(sel["chances"].sum()) if sel["chances"].notna().any() else NAN
        rows.append(
            {
                "metric": metric,
                "condition": cond,
                "group": group,
                "level": level,
                **describe(vals),
                "successes": successes,
                "chances": chances,
                "proportion": successes / chances if chances and chances > 0 else NAN,
            }
        )
    return pd.DataFrame(rows)


def _proportions_table(plan: AnalysisPlan, prep: Prepared) -> pd.DataFrame:
    """Pooled proportions with 95% Wilson intervals per condition, overall and per level (figures)."""
    rows = []
    for metric in plan.metrics:
        if plan.metric_kind(metric) != "proportion":
            continue
        data = prep.frame[prep.frame["metric"] == metric]
        for by_level in (False, True):
            if by_level and not data["level"].notna().any():
                continue
            keys = ["condition", "level"] if by_level else ["condition"]
            for key, sel in data.groupby(keys, sort=False, dropna=False):
                key = key if isinstance(key, tuple) else (key,)
                x, n = int(sel["value"].sum()), int(sel["denominator"].sum())
                try:
                    w = stats.wilson_interval(x, n)
                    est, lo, hi = _f(w.estimate), _f(w.lower), _f(w.upper)
                except StudyctlError:
                    est = lo = hi = NAN
                rows.append(
                    {
                        "metric": metric,
                        "condition": key[0],
                        "level": key[1] if by_level else None,
                        "successes": x,
                        "chances": n,
                        "participants": sel["participant"].nunique(),
                        "estimate": est,
                        "ci_low": lo,
                        "ci_high": hi,
                        "ci_level": 0.95,
                    }
                )
    cols = [
        "metric",
        "condition",
        "level",
        "successes",
        "chances",
        "participants",
        "estimate",
        "ci_low",
        "ci_high",
        "ci_level",
    ]
    return pd.DataFrame(rows, columns=cols)


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
    units = _units_table(plan, prep)
    frames = {name: pd.DataFrame(rows_) for name, rows_ in tables.items() if rows_}
    frames["units"] = units
    frames["cells"] = _cells_table(plan, units) if not units.empty else pd.DataFrame()
    frames["proportions"] = _proportions_table(plan, prep)
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
