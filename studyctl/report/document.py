"""The report's content as neutral blocks, laid out for an analyst who pastes from it.

Order: title block, table of contents, summary of findings (the headline of every analysis and the
simulated-vs-published agreement), statistical methods (generated from the plan), descriptives, each
analysis (APA line, then a tidy table), figures, simulated vs published, missing data, notes.
The blocks are rendered to HTML and Markdown by the Jinja2 templates of :mod:`studyctl.report.render`.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from studyctl import __version__
from studyctl.analysis import catalog
from studyctl.analysis.results import split_levels
from studyctl.report import apa
from studyctl.report.compose import likert_items_table
from studyctl.report.findings import (
    agreement_headline,
    headline_lines,
    methods_text,
    posthoc_text,
    tests_frame,
    where_text,
)
from studyctl.report.render import Block, render_html, render_latex, render_markdown
from studyctl.report.style import fmt_num

if TYPE_CHECKING:
    from collections.abc import Mapping

    from studyctl.analysis.plan import PlanTest
    from studyctl.analysis.results import AnalysisResult

ROLE_TITLES = {
    "paper": "Results: the paper's analysis",
    "within_subject": "Within-subject analysis (what the design calls for)",
    "supplementary": "Supplementary tables",
}

__all__ = ["blocks", "html", "markdown", "render_html", "render_markdown", "summary"]


def _isnan(x: Any) -> bool:
    return x is None or (isinstance(x, float | np.floating) and math.isnan(x))


def _sig(v: Any) -> str:
    return "" if v is None or _isnan(v) else ("yes" if bool(v) else "no")


def _p_cell(p: float) -> str:
    """p as a table cell: ``.023``, ``< .001`` (the column header says p)."""
    return apa.p_text(p, name="").strip().removeprefix("= ")


def relative_source(source: str, base: Path | str | None) -> str:
    """The data source with its local path made relative to ``base`` (the report's folder), never absolute."""
    if not source:
        return "in-memory table"
    path, sep, rest = source.partition(" (")
    if not os.path.isabs(path):
        return source
    rel = os.path.relpath(path, base) if base is not None else Path(path).name
    if rel.split(os.sep).count("..") > 2:  # far from the report (e.g. a shipped data file): its name only
        rel = Path(path).name
    return rel + sep + rest


# ------------------------------------------------------------------------------------------ tidy tables


def tidy(head: list[str], body: list[list[str]], *, keep: Sequence[str] = ()) -> tuple[list[str], list[list[str]],
                                                                                          str]:
    """Drop empty columns and columns repeating another, and lift columns with one value into a caption.

    Returns (head, body, caption). ``keep`` are headers never lifted (the first column of a table).
    """
    cols = list(range(len(head)))
    empty = {"", "–", "nan", "None"}
    cols = [c for c in cols if any(str(r[c]) not in empty for r in body)]
    seen: dict[tuple[str, ...], int] = {}
    unique = []
    for c in cols:
        values = tuple(str(r[c]) for r in body)
        if values in seen:
            continue
        seen[values] = c
        unique.append(c)
    cols = unique
    caption = []
    if len(body) > 1:
        for c in list(cols):
            values = {str(r[c]) for r in body}
            if len(values) == 1 and head[c] not in keep and len(cols) > 2 and head[c] in _LIFTABLE:
                caption.append(f"{head[c]}: {values.pop()}")
                cols.remove(c)
    return [head[c] for c in cols], [[r[c] for c in cols] for r in body], "; ".join(caption)


# Columns whose single value is said once under the table instead of in every row.
_LIFTABLE = {"metric", "method", "test", "adjustment", "alpha", "n", "n per level"}


def _n_cells(r: pd.Series) -> tuple[str, str]:
    per = str(r["n_per_group"] or "")
    parts = [p.strip() for p in per.split(";") if p.strip()]
    return str(r["n"]), ("" if len(set(parts)) <= 1 else per)


def _test_rows_table(entry: PlanTest, rows: pd.DataFrame, result: AnalysisResult) -> tuple[list[str], list, str]:
    """One tidy table of an entry's rows (omnibus, two-sample, post-hoc pairs or intervals)."""
    label = result.plan.metric_label
    factors = list(entry.by)
    stat_names = {str(s) for s in rows["statistic_name"] if s}
    es_names = {str(s) for s in rows["effect_size_name"] if s}
    adjust = {str(s) for s in rows["p_adjust"] if s and s != "none"}
    head = ["metric", *factors, "comparison", "n", "n per level"]
    kinds = set(rows["kind"])
    intervals = kinds == {"interval"} or set(rows["test"]) == {"newcombe"}
    if intervals:
        head += ["x / n", "estimate", "95% CI", "significant"]
    else:
        stat_head = apa.STAT_SYMBOLS.get(next(iter(stat_names)), next(iter(stat_names))) if len(stat_names) == 1 \
            else "statistic"
        if stat_head.startswith("diff"):
            stat_head = "Δ (second − first)"
        es_head = apa.EFFECT_SYMBOLS.get(next(iter(es_names)), "effect size") if len(es_names) == 1 else "effect size"
        p_adj_head = f"p ({next(iter(adjust))})" if len(adjust) == 1 else "p adj."
        head += [stat_head, "df", "z", "W critical", "p", p_adj_head, es_head, f"{es_head} 95% CI (bootstrap)",
                 "95% CI", "significant"]
    head += ["method", "notes"]
    body = []
    for _, r in rows.iterrows():
        split = split_levels(r["split"])
        n, per = _n_cells(r)
        groups = str(r["groups"])
        cells = [label(r["metric"]), *[split.get(f, "") for f in factors], groups, n, per]
        ci = apa.ci_text(r["ci_low"], r["ci_high"], r["ci_level"]).split("CI ", 1)[-1] if not _isnan(r["ci_low"]) \
            else ""
        if intervals:
            est = r["estimate"]
            cells += [r["n_per_group"] if r["kind"] == "interval" else r["n_per_group"],
                      "" if _isnan(est) else fmt_num(est), ci, _sig(r["significant"])]
        else:
            stat = "" if _isnan(r["statistic"]) else apa.number(r["statistic"])
            if len(stat_names) > 1 and r["statistic_name"]:
                stat = f"{apa.STAT_SYMBOLS.get(r['statistic_name'], r['statistic_name'])} = {stat}"
            df = apa.df_text(r["df"]) + (f", {apa.df_text(r['df2'])}" if not _isnan(r.get("df2")) else "")
            if r["critical_value"] == r["critical_value"]:  # W against its critical value: df is n_r
                df = ""
            es = "" if _isnan(r["effect_size"]) else (
                apa.effect_text(r["effect_size_name"], r["effect_size"]).split(" = ", 1)[1] if len(es_names) == 1
                else apa.effect_text(r["effect_size_name"], r["effect_size"]))
            p_adj = _p_cell(r["p_adj"]) if len(adjust) <= 1 else apa.p_text(r["p_adj"], name=f"p_{r['p_adjust']}")
            es_ci = ""
            if not _isnan(r.get("effect_ci_low")) and not _isnan(r.get("effect_ci_high")):
                bounded = abs(r["effect_ci_low"]) <= 1 and abs(r["effect_ci_high"]) <= 1
                fmt = apa.bounded if bounded else apa.number
                es_ci = f"[{fmt(r['effect_ci_low'])}, {fmt(r['effect_ci_high'])}]"
            cells += [stat, df, "" if _isnan(r["z"]) else apa.number(r["z"]),
                      "" if _isnan(r["critical_value"]) else apa.number(r["critical_value"]), _p_cell(r["p"]), p_adj,
                      es, es_ci, ci, _sig(r["significant"])]
        note = str(r["warnings"] or "")
        cells += [str(r["method"] or ""), ("NOT COMPUTED: " + note) if r["status"] != "ok" else note]
        body.append(cells)
    return tidy(head, body, keep=("metric", "comparison"))


def _label_unit(plan: object, metric_id: str) -> str:
    """A metric's label with its unit, for tables whose numbers are in that unit ("Completion time (s)")."""
    unit = plan.metric_unit(metric_id)
    return f"{plan.metric_label(metric_id)} ({unit})" if unit else plan.metric_label(metric_id)


def _descriptive_table(frame: pd.DataFrame, result: AnalysisResult, level_name: str) -> tuple[list[str], list, str]:
    head = ["metric", "split", level_name, "n", "mean", "SD", "SE", "median", "IQR", "min – max"]
    body = [
        [
            _label_unit(result.plan, r["metric"]),
            r["split"],
            r["level"],
            str(int(r["n"])),
            fmt_num(r["mean"]),
            fmt_num(r["sd"]),
            fmt_num(r["se"]),
            fmt_num(r["median"]),
            f"{fmt_num(r['q1'])} – {fmt_num(r['q3'])}",
            f"{fmt_num(r['min'])} – {fmt_num(r['max'])}",
        ]
        for _, r in frame.iterrows()
    ]
    return tidy(head, body, keep=("metric",))


def _coefficient_table(coef: pd.DataFrame, result: AnalysisResult) -> tuple[list[str], list, str]:
    head = ["metric", "split", "coefficient", "estimate", "SE", "95% CI"]
    body = []
    for r in coef.itertuples(index=False):
        if r.status != "ok":
            body.append([result.plan.metric_label(r.metric), r.split, "–", "", "", f"not computed: {r.reason}"])
            continue
        body.append([result.plan.metric_label(r.metric), r.split, r.coefficient, fmt_num(r.estimate), fmt_num(r.se),
                     f"[{fmt_num(r.ci_low)}, {fmt_num(r.ci_high)}]"])
    head, body, caption = tidy(head, body, keep=("metric",))
    return head, body, "; ".join(x for x in (caption, str(coef["method"].iloc[0])) if x)


# ------------------------------------------------------------------------------------------- sections


def _entry_blocks(entry: PlanTest, result: AnalysisResult) -> list[Block]:
    name = catalog.ALIASES.get(entry.test, entry.test)
    blocks: list[Block] = [("h", 3, entry.title or entry.id, entry.id)]
    if entry.description:
        blocks.append(("p", entry.description))
    frame = tests_frame(result)
    rows = frame[frame["test_id"] == entry.id]
    if name == "percent_change":
        pct = result.tables.get("percent_change", pd.DataFrame())
        pct = pct[pct["test_id"] == entry.id] if not pct.empty else pct
        if not pct.empty:
            levels = list(dict.fromkeys(pct["level"]))
            head = [
                "metric",
                *[f"{lv} mean" for lv in levels],
                *[f"{lv} % vs {entry.reference}" for lv in levels if lv != entry.reference],
            ]
            body = []
            for mid, sel in pct.groupby("metric", sort=False):
                means = [fmt_num(float(sel.loc[sel["level"] == lv, "mean"].iloc[0])) for lv in levels]
                pcts = [
                    f"{float(sel.loc[sel['level'] == lv, 'percent_change'].iloc[0]):+.1f}%"
                    for lv in levels
                    if lv != entry.reference
                ]
                body.append([_label_unit(result.plan, mid), *means, *pcts])
            blocks.append(("table", head, body, ""))
    elif name == "likert_table":
        for mid in entry.metrics:
            table = likert_items_table(result, mid)
            table = table[table["test_id"] == entry.id] if not table.empty else table
            if table.empty:
                blocks.append(("alert", f"no answers for {mid}"))
                continue
            levels = list(dict.fromkeys(table["level"]))
            if entry.compare == "item":
                head = ["item", "n", "mean", "SD", "median"]
                body = [
                    [r["level"], str(int(r["n"])), fmt_num(r["mean"]), fmt_num(r["sd"]), fmt_num(r["median"])]
                    for _, r in table.iterrows()
                ]
            else:
                head = ["item", *levels]
                body = []
                for item, sel in table.groupby("item", sort=False):
                    cells = []
                    for lv in levels:
                        row = sel[sel["level"] == lv]
                        cells.append(
                            "–" if row.empty else f"{float(row['mean'].iloc[0]):.2f} (n={int(row['n'].iloc[0])})"
                        )
                    body.append([item.replace("_", " "), *cells])
            blocks.append(("table", head, body, ""))
    elif name == "descriptive":
        desc = result.tables.get("descriptives", pd.DataFrame())
        desc = desc[desc["test_id"] == entry.id] if not desc.empty else desc
        if not desc.empty:
            blocks.append(("table", *_descriptive_table(desc, result, entry.compare)))
    elif rows.empty:
        blocks.append(("alert", "no rows: nothing could be computed for this entry"))
    else:
        main = rows[rows["kind"] != "posthoc"]
        lines = [f"{where_text(r, result)}: {apa.line(r._asdict())}" for r in main.itertuples(index=False)
                 if r.kind in ("omnibus", "two_sample")]
        if lines:
            blocks.append(("apa", lines))
        if not main.empty:
            blocks.append(("table", *_test_rows_table(entry, main, result)))
        post = rows[rows["kind"] == "posthoc"]
        if not post.empty:
            blocks.append(("p", f"Post-hoc pairs ({posthoc_text(entry)}):"))
            blocks.append(("table", *_test_rows_table(entry, post, result)))
        coef = result.tables.get("model_coefficients")
        coef = coef[coef["test_id"] == entry.id] if coef is not None and not coef.empty else None
        if coef is not None and not coef.empty:
            blocks.append(("p", "Coefficients in treatment coding (the first level is the reference; "
                                + ("log odds ratios" if name == "ordinal" else "in the metric's unit")
                                + f"), Wald {float(coef['ci_level'].iloc[0]):.0%} intervals:"))
            blocks.append(("table", *_coefficient_table(coef, result)))
    if entry.published:
        text = ", ".join(f"{k} = {v}" for k, v in entry.published.items())
        blocks.append(("p", f"Published values (the paper): {text}."))
    return blocks


def _source_line(result: AnalysisResult, base: Path | str | None) -> str:
    info = result.data.info
    bits = [f"data: {relative_source(result.data.source, base)}"]
    for key in ("participants", "trials_completed", "kind"):
        if key in info:
            bits.append(f"{key.replace('_', ' ')}: {info[key]}")
    if "trials_other" in info:
        other = info["trials_other"] or {}
        bits.append("other trials: " + (", ".join(f"{v} {k}" for k, v in other.items()) or "none"))
    return "; ".join(bits)


def _cells_table(result: AnalysisResult) -> tuple[list[str], list, str]:
    plan = result.plan
    cells = result.tables.get("cells", pd.DataFrame())
    head = ["metric", "condition", "group", "level", "n", "mean", "SD", "median", "IQR", "successes / chances"]
    body = [
        [
            _label_unit(plan, r["metric"]),
            "" if _isnan(r["condition"]) else r["condition"],  # an end-of-study questionnaire has none
            "" if _isnan(r["group"]) else r["group"],
            "" if _isnan(r["level"]) else r["level"],
            str(int(r["n"])),
            fmt_num(r["mean"]),
            fmt_num(r["sd"]),
            fmt_num(r["median"]),
            f"{fmt_num(r['q1'])} – {fmt_num(r['q3'])}",
            "" if _isnan(r["chances"]) else f"{int(r['successes'])} / {int(r['chances'])}",
        ]
        for _, r in cells.iterrows()
    ]
    return tidy(head, body, keep=("metric",))


def blocks(
    result: AnalysisResult, figure_ids: Sequence[str], problems: Sequence[str], *, base: Path | str | None = None
) -> list[Block]:
    """The report's content as neutral blocks (rendered to HTML or Markdown); paths relative to ``base``."""
    plan = result.plan
    out: list[Block] = [("h", 1, plan.title, "top")]
    meta = [
        f"study (protocol): {plan.study}",
        _source_line(result, base),
        f"generated by studyctl {__version__} on {_dt.datetime.now(_dt.UTC):%Y-%m-%d %H:%M} UTC",
    ]
    if plan.paper:
        meta.insert(0, f"paper: {plan.paper}")
    out.append(("meta", meta))
    out.append(("toc",))

    # Summary of findings: what an analyst reads first.
    out.append(("h", 2, "Summary of findings", "summary"))
    if problems or result.partial:
        out.append(("alert", "PARTIAL RESULTS: some of what the plan asks for could not be computed "
                    "(listed under Missing data and marked NOT COMPUTED in the tables)."))
    findings = []
    agreement = agreement_headline(result)
    if agreement:  # one line, first: how far a simulated study is from the paper
        findings.append(("Simulated vs published", "simulated-vs-published", [agreement]))
    for entry in plan.tests:
        if entry.role == "supplementary":
            continue
        lines = headline_lines(entry, result)
        if lines:
            findings.append((entry.title or entry.id, entry.id, lines))
    out.append(("findings", findings))

    out.append(("h", 2, "Statistical methods", "methods"))
    out.extend(("p", t) for t in methods_text(result))

    if not result.tables.get("cells", pd.DataFrame()).empty:
        out.append(("h", 2, "Descriptive statistics per condition and group", "descriptives"))
        out.append(("table", *_cells_table(result)))

    for role in ("paper", "within_subject", "supplementary"):
        entries = [e for e in plan.tests if e.role == role]
        if not entries:
            continue
        out.append(("h", 2, ROLE_TITLES[role], role.replace("_", "-")))
        for entry in entries:
            out.extend(_entry_blocks(entry, result))
    if figure_ids:
        out.append(("h", 2, "Figures", "figures"))
        letter = 0
        for spec in plan.figures:
            if spec.id in figure_ids:
                letter += 1
                out.append(("figure", spec.id, f"Figure {letter}. {spec.title or spec.id}", spec.title or spec.id))
    if "agreement_info" in result.tables:  # a simulated study: how it compares with the paper
        from studyctl.report.calibration import agreement_blocks

        out.extend(agreement_blocks(result.tables.get("agreement"), result.tables["agreement_info"],
                                    units={m: result.plan.metric_unit(m) for m in result.plan.metrics}))
    out.append(("h", 2, "Missing data", "missing"))
    if problems:
        out.append(("list", list(problems)))
    if result.missing.empty:
        out.append(("p", "No value is missing."))
    else:
        out.append(
            ("p", f"{len(result.missing)} value(s) could not be computed or were left out (policy: {plan.missing}):")
        )
        head = list(result.missing.columns)
        body = [["" if _isnan(v) else str(v) for v in row] for row in result.missing.itertuples(index=False)]
        out.append(("table", head, body, ""))
    notes = result.tables.get("notes")
    if notes is not None and not notes.empty:
        out.append(("h", 2, "Notes", "notes"))
        out.append(("list", list(notes["note"])))
    return out


def html(
    result: AnalysisResult, figures: Mapping[str, bytes], problems: Sequence[str], *, base: Path | str | None = None
) -> str:
    """The self-contained HTML report."""
    return render_html(result.plan.title, blocks(result, list(figures), problems, base=base), figures)


def markdown(
    result: AnalysisResult, figure_files: Sequence[str], problems: Sequence[str], *, base: Path | str | None = None
) -> str:
    """The report as Markdown; figures are linked from ``figures/``."""
    ids = [re.sub(r"\.(png|svg|pdf)$", "", f) for f in figure_files]
    return render_markdown(blocks(result, list(dict.fromkeys(ids)), problems, base=base))


def latex_tables(result: AnalysisResult, problems: Sequence[str], *, base: Path | str | None = None) -> str:
    """Every table of the report as LaTeX (booktabs), captioned by its section."""
    return render_latex(result.plan.title, blocks(result, [], problems, base=base))


def summary(result: AnalysisResult, problems: Sequence[str], *, base: Path | str | None = None) -> dict[str, Any]:
    """Headline facts for scripts and the demo: counts, partial flag, problems, significant findings."""
    frame = result.to_frame()
    significant = frame[(frame["status"] == "ok") & (frame["significant"] == True)]  # noqa: E712
    return {
        "study": result.plan.study,
        "title": result.plan.title,
        "source": relative_source(result.data.source, base) if base is not None else result.data.source,
        "data": dict(result.data.info),
        "partial": bool(result.partial or problems),
        "problems": list(problems),
        "tests": int(len(frame)),
        "not_computed": int((frame["status"] != "ok").sum()),
        "significant": [
            f"{r.test_id}/{r.metric}{f' [{r.split}]' if r.split else ''} {r.groups}" for r in significant.itertuples()
        ],
        "headlines": {e.id: headline_lines(e, result) for e in result.plan.tests if e.role != "supplementary"},
        "missing_values": int(len(result.missing)),
        "timings_s": dict(result.timings),
    }
