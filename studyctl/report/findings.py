"""What the report says in sentences: the headline of each analysis and of the simulated-vs-published agreement
(summary of findings), and the statistical-methods paragraphs generated from the plan.

:mod:`studyctl.report.document` places them among its blocks; the tests table they read (:func:`tests_frame`) is
the one its tidy tables show.
"""

from __future__ import annotations

import platform
from importlib import metadata
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from studyctl import __version__
from studyctl.analysis import catalog
from studyctl.analysis.results import split_levels
from studyctl.report import apa

if TYPE_CHECKING:
    from studyctl.analysis.plan import PlanTest
    from studyctl.analysis.results import AnalysisResult


def tests_frame(result: AnalysisResult) -> pd.DataFrame:
    """The tests table with the bootstrap intervals of the effect sizes (``effect_ci_low/high``) when the
    result has them (table ``effect_sizes``)."""
    frame = result.to_frame()
    ci = result.tables.get("effect_sizes")
    if ci is None or ci.empty:
        return frame.assign(effect_ci_low=np.nan, effect_ci_high=np.nan)
    keys = ["test_id", "metric", "split", "groups"]
    ci = ci[keys + ["ci_low", "ci_high"]].rename(columns={"ci_low": "effect_ci_low", "ci_high": "effect_ci_high"})
    return frame.merge(ci, on=keys, how="left")


# ------------------------------------------------------------------------------------------- headlines


def where_text(r: Any, result: AnalysisResult, with_metric: bool = True) -> str:
    bits = [result.plan.metric_label(r.metric)] if with_metric else []
    if r.split:
        bits.append(", ".join(f"{k} {v}" for k, v in split_levels(r.split).items()))
    if r.kind in ("two_sample", "posthoc", "pairwise", "interval") and r.groups:
        bits.append(str(r.groups))
    return ", ".join(bits)


def headline_lines(entry: PlanTest, result: AnalysisResult) -> list[str]:
    """The entry's headline: one APA line per test (up to four), else the count significant and the strongest."""
    frame = tests_frame(result)
    rows = frame[(frame["test_id"] == entry.id) & (frame["kind"].isin(["omnibus", "two_sample"]))]
    if rows.empty:  # pairwise-only entries (signed-rank pairs against W_critical, Newcombe margins)
        rows = frame[(frame["test_id"] == entry.id) & (frame["kind"] == "pairwise")]
    name = catalog.ALIASES.get(entry.test, entry.test)
    if name in ("percent_change", "likert_table", "descriptive"):  # tables, not tests: read in their section
        return []
    if rows.empty:
        intervals = frame[(frame["test_id"] == entry.id) & (frame["kind"] == "interval") & frame["estimate"].notna()]
        if not intervals.empty:
            lo, hi = intervals.loc[intervals["estimate"].idxmin()], intervals.loc[intervals["estimate"].idxmax()]
            if lo["estimate"] == hi["estimate"]:
                return [f"{len(intervals)} intervals, every estimate p̂ = {apa.bounded(lo['estimate'])}"]
            return [f"{len(intervals)} intervals; lowest {where_text(lo, result)}: {apa.line(lo.to_dict())}; highest "
                    f"{where_text(hi, result)}: {apa.line(hi.to_dict())}"]
        return []
    ok = rows[rows["status"] == "ok"]
    lines = []
    if len(rows) <= 4:
        for r in rows.itertuples(index=False):
            lines.append(f"{where_text(r, result)}: {apa.line(r._asdict())}")
        return lines
    sig = ok[ok["significant"] == True]  # noqa: E712
    what = "pairs" if set(rows["kind"]) == {"pairwise"} else "tests"
    lines.append(f"{len(sig)} of {len(rows)} {what} significant at α = {apa.bounded(float(rows['alpha'].iloc[0]))}"
                 + (f" ({len(rows) - len(ok)} not computed)" if len(ok) < len(rows) else ""))
    p = ok["p"].where(ok["p"].notna(), ok["p_adj"]) if not ok.empty else ok.get("p")
    if not ok.empty and p.notna().any():
        best = ok.loc[p.idxmin()]
        lines.append(f"strongest: {where_text(best, result)}: {apa.line(best.to_dict())}")
    return lines


def agreement_headline(result: AnalysisResult) -> str | None:
    frame = result.tables.get("agreement")
    if frame is None or frame.empty:
        return None
    from studyctl.calibration.agreement import summary_from_frame

    s = summary_from_frame(frame).get("all") or {}
    if not s.get("targets"):
        return None

    def frac(key: str) -> str:
        f, n = s.get(f"{key}_fraction"), s.get(f"{key}_n")
        return "–" if f is None or not n else f"{round(f * n)}/{n} ({f:.0%})"

    chance = ""
    if s.get("verdict_p_n"):
        # beside the verdicts, what a same-size replication of the paper itself would reproduce of those with a p
        chance = f" ({s['verdict_p_reproduced']} of the {s['verdict_p_n']} with a published p, where a same-size " \
                 f"replication of the paper would reproduce {s['verdict_expected']:.1f})"
    band_chance = ""
    if s.get("within_p_n"):
        band_chance = f" ({s['within_p_reproduced']} of the {s['within_p_n']} whose band is the paper's sampling " \
                      f"interval, where a same-size replication of the paper would place {s['within_expected']:.1f})"
    return (f"{frac('agree')} published targets agree on every check; directions right {frac('direction')}; "
            f"verdicts reproduced {frac('verdict')}{chance}; within the published band {frac('within')}{band_chance}")


# --------------------------------------------------------------------------------------------- methods


def _versions() -> str:
    names = ("numpy", "scipy", "pandas", "statsmodels")
    found = []
    for n in names:
        try:
            found.append(f"{n} {metadata.version(n)}")
        except metadata.PackageNotFoundError:
            continue
    return f"studyctl {__version__} (Python {platform.python_version()}; {', '.join(found)})"


def posthoc_text(entry: PlanTest) -> str:
    ph = entry.posthoc
    if ph.test == "multcompare":
        how = "MATLAB multcompare: studentized range on mean ranks"
    elif ph.test == "tukey_hsd":
        how = "Tukey HSD, studentized range"
    else:
        how = f"{ph.test.replace('_', ' ')}, {ph.p_adjust}-adjusted"
    when = "after a significant omnibus test" if ph.when == "significant" else "always"
    return f"{how}, {when}"


def methods_text(result: AnalysisResult) -> list[str]:
    """The statistical-analysis paragraph(s), generated from the plan."""
    plan = result.plan
    agg = {"mean": "averaged", "median": "summarised by their median", "none": "kept as separate rows"}.get(
        plan.aggregate, f"aggregated by {plan.aggregate}")
    paras = [f"Repeated trials of a participant in one condition were {agg}, giving one value per participant and "
             f"cell. Missing values: {plan.missing} (every missing value is listed under Missing data). Tests were "
             f"two-sided unless stated, at α = {apa.bounded(plan.alpha)}."]
    for entry in plan.tests:
        name = catalog.ALIASES.get(entry.test, entry.test)
        spec = catalog.TESTS[name]
        if spec.design == catalog.DESCRIPTIVE:
            continue
        text = f"{entry.title or entry.id}: {spec.summary}, comparing the levels of {entry.compare.replace('_', ' ')}"
        if "factor" in spec.options and "factor" in entry.options:  # a model's second factor (group × condition)
            text += f" crossed with {str(entry.options['factor']).replace('_', ' ')}"
        if entry.by:
            text += f" separately for each {' × '.join(b.replace('_', ' ') for b in entry.by)}"
        if entry.posthoc:
            text += f"; post-hoc pairs: {posthoc_text(entry)}"
        if entry.correction != "none":
            text += f"; p-values adjusted across rows ({entry.correction})"
        if entry.effect_size:
            text += f"; effect size: {', '.join(apa.EFFECT_SYMBOLS.get(e, e) for e in entry.effect_size)}"
        paras.append(text + ".")
    ci = result.tables.get("effect_sizes")
    if ci is not None and not ci.empty:
        paras.append(f"Effect sizes are given with 95% percentile-bootstrap intervals ({int(ci['replicates'].max())} "
                     f"resamples, seeded generator, seed {int(ci['seed'].iloc[0])}; participants resampled within "
                     "each level for independent samples and as whole blocks for paired designs).")
    paras.append(f"Computed with {_versions()}.")
    return paras
