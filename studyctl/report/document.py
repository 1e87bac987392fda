"""The report documents: self-contained HTML (figures embedded as base64 PNG), Markdown, and a summary."""

from __future__ import annotations

import base64
import datetime as _dt
import html as _html
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from studyctl import __version__
from studyctl.analysis import catalog
from studyctl.report.compose import likert_items_table
from studyctl.report.style import fmt_num, fmt_p

if TYPE_CHECKING:
    from studyctl.analysis.plan import PlanTest
    from studyctl.analysis.results import AnalysisResult

ROLE_TITLES = {
    "paper": "Results: the paper's analysis",
    "within_subject": "Within-subject analysis (what the design calls for)",
    "supplementary": "Supplementary tables",
}

# A section is a list of blocks: ("h", level, text) | ("p", text) | ("table", headers, rows) |
# ("figure", id, caption) | ("alert", text) | ("list", items)
Block = tuple


def _isnan(x: Any) -> bool:
    return x is None or (isinstance(x, float | np.floating) and math.isnan(x))


def _sig(v: Any) -> str:
    return "–" if v is None or _isnan(v) else ("yes" if bool(v) else "no")


def _test_table(entry: PlanTest, rows: pd.DataFrame, result: AnalysisResult) -> tuple[list[str], list[list[str]]]:
    name = catalog.ALIASES.get(entry.test, entry.test)
    label = result.plan.metric_label

    def warn(r: pd.Series) -> str:
        text = str(r["warnings"] or "")
        return ("NOT COMPUTED: " + text) if r["status"] != "ok" else text

    if name == "wilson":
        head = ["metric", "split", "level", "x / n", "estimate", "95% CI", "method", "notes"]
        body = [
            [
                label(r["metric"]),
                r["split"],
                r["groups"],
                r["n_per_group"],
                fmt_num(r["estimate"]),
                f"{fmt_num(r['ci_low'])} – {fmt_num(r['ci_high'])}",
                r["method"],
                warn(r),
            ]
            for _, r in rows.iterrows()
        ]
        return head, body
    if name == "newcombe":
        head = ["metric", "pair", "x / n", "Δp", "margin (CI)", "interval of Δp", "significant", "notes"]
        body = [
            [
                label(r["metric"]),
                r["groups"],
                r["n_per_group"],
                fmt_num(r["estimate"]),
                fmt_num(r["statistic"]),
                f"{fmt_num(r['ci_low'])} – {fmt_num(r['ci_high'])}",
                _sig(r["significant"]),
                warn(r),
            ]
            for _, r in rows.iterrows()
        ]
        return head, body
    if name == "signed_rank" and entry.options.get("critical_value"):
        head = ["metric", "split", "pair", "n_r", "W", "W_critical", "significant (W ≤ W_crit)", "p", "method", "notes"]
        body = [
            [
                label(r["metric"]),
                r["split"],
                r["groups"],
                fmt_num(r["df"]),
                fmt_num(r["statistic"]),
                fmt_num(r["critical_value"]),
                _sig(r["significant"]),
                fmt_p(r["p"]),
                r["method"],
                warn(r),
            ]
            for _, r in rows.iterrows()
        ]
        return head, body
    head = [
        "metric",
        "split",
        "kind",
        "groups",
        "n",
        "statistic",
        "df",
        "p",
        "p adj.",
        "effect size",
        "CI",
        "significant",
        "method",
        "notes",
    ]
    body = []
    for _, r in rows.iterrows():
        stat = f"{r['statistic_name']} = {fmt_num(r['statistic'])}" if r["statistic_name"] else "–"
        es = f"{r['effect_size_name']} = {fmt_num(r['effect_size'])}" if r["effect_size_name"] else "–"
        ci = "–" if _isnan(r["ci_low"]) else f"{fmt_num(r['ci_low'])} – {fmt_num(r['ci_high'])}"
        p_adj = "–" if _isnan(r["p_adj"]) else f"{fmt_p(r['p_adj'])} ({r['p_adjust']})"
        body.append(
            [
                label(r["metric"]),
                r["split"],
                r["kind"],
                r["groups"],
                f"{r['n']} ({r['n_per_group']})",
                stat,
                fmt_num(r["df"]),
                fmt_p(r["p"]),
                p_adj,
                es,
                ci,
                _sig(r["significant"]),
                r["method"],
                warn(r),
            ]
        )
    return head, body


def _descriptive_table(frame: pd.DataFrame, result: AnalysisResult, level_name: str) -> tuple[list[str], list]:
    head = ["metric", "split", level_name, "n", "mean", "SD", "SE", "median", "IQR", "min – max"]
    body = [
        [
            result.plan.metric_label(r["metric"]),
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
    return head, body


def _published(entry: PlanTest) -> Block | None:
    if not entry.published:
        return None
    text = ", ".join(f"{k} = {v}" for k, v in entry.published.items())
    return ("p", f"Published values (the paper): {text}.")


def _posthoc_text(entry: PlanTest) -> str:
    ph = entry.posthoc
    if ph.test == "multcompare":
        how = "MATLAB multcompare: studentized range on mean ranks"
    elif ph.test == "tukey_hsd":
        how = "studentized range"
    else:
        how = f"{ph.p_adjust}-adjusted"
    when = "after a significant omnibus test" if ph.when == "significant" else "always"
    return f"{ph.test} ({how}, {when})"


def _entry_blocks(entry: PlanTest, result: AnalysisResult) -> list[Block]:
    name = catalog.ALIASES.get(entry.test, entry.test)
    blocks: list[Block] = [("h", 3, entry.title or entry.id)]
    spec = catalog.TESTS[name]
    blocks.append(
        (
            "p",
            f"{spec.summary}. Compared: {entry.compare}"
            + (f"; separately for each {', '.join(entry.by)}" if entry.by else "")
            + (f"; post-hoc: {_posthoc_text(entry)}" if entry.posthoc else "")
            + (f"; correction across rows: {entry.correction}" if entry.correction != "none" else "")
            + f"; alpha = {entry.alpha if entry.alpha is not None else result.plan.alpha}.",
        )
    )
    if entry.description:
        blocks.append(("p", entry.description))
    frame = result.to_frame()
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
                body.append([result.plan.metric_label(mid), *means, *pcts])
            blocks.append(("table", head, body))
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
            blocks.append(("table", head, body))
    elif name == "descriptive":
        desc = result.tables.get("descriptives", pd.DataFrame())
        desc = desc[desc["test_id"] == entry.id] if not desc.empty else desc
        if not desc.empty:
            blocks.append(("table", *_descriptive_table(desc, result, entry.compare)))
    elif rows.empty:
        blocks.append(("alert", "no rows: nothing could be computed for this entry"))
    else:
        blocks.append(("table", *_test_table(entry, rows, result)))
    pub = _published(entry)
    if pub:
        blocks.append(pub)
    return blocks


def _source_line(result: AnalysisResult) -> str:
    info = result.data.info
    bits = [f"data: {result.data.source or 'in-memory table'}"]
    for key in ("participants", "trials_completed", "kind"):
        if key in info:
            bits.append(f"{key.replace('_', ' ')}: {info[key]}")
    if "trials_other" in info:
        other = info["trials_other"] or {}
        bits.append("other trials: " + (", ".join(f"{v} {k}" for k, v in other.items()) or "none"))
    return "; ".join(bits)


def blocks(result: AnalysisResult, figure_ids: Sequence[str], problems: Sequence[str]) -> list[Block]:
    """The report's content as neutral blocks (rendered to HTML or Markdown)."""
    plan = result.plan
    out: list[Block] = [("h", 1, plan.title)]
    meta = [
        f"study (protocol): {plan.study}",
        _source_line(result),
        f"generated by studyctl {__version__} on {_dt.datetime.now(_dt.UTC):%Y-%m-%d %H:%M} UTC",
        f"alpha = {plan.alpha}; missing data: {plan.missing}; repetitions aggregated by: {plan.aggregate}",
    ]
    if plan.paper:
        meta.insert(0, f"paper: {plan.paper}")
    out.append(("list", meta))
    if problems or result.partial:
        out.append(
            (
                "alert",
                "PARTIAL RESULTS: some of what the plan asks for could not be computed. "
                "Every gap is listed here and marked NOT COMPUTED in the tables.",
            )
        )
        out.append(("list", list(problems) or ["see rows marked NOT COMPUTED"]))
    if "agreement_info" in result.tables:  # a simulated study: how it compares with the paper, first
        from studyctl.report.calibration import agreement_blocks

        out.extend(agreement_blocks(result.tables.get("agreement"), result.tables["agreement_info"]))
    for role in ("paper", "within_subject", "supplementary"):
        entries = [e for e in plan.tests if e.role == role]
        if not entries:
            continue
        out.append(("h", 2, ROLE_TITLES[role]))
        for entry in entries:
            out.extend(_entry_blocks(entry, result))
    if figure_ids:
        out.append(("h", 2, "Figures"))
        for spec in plan.figures:
            if spec.id in figure_ids:
                out.append(("figure", spec.id, spec.title or spec.id))
    cells = result.tables.get("cells", pd.DataFrame())
    if not cells.empty:
        out.append(("h", 2, "Values per condition and group"))
        head = ["metric", "condition", "group", "level", "n", "mean", "SD", "median", "IQR", "successes / chances"]
        body = [
            [
                plan.metric_label(r["metric"]),
                r["condition"],
                r["group"],
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
        out.append(("table", head, body))
    out.append(("h", 2, "Missing data"))
    if result.missing.empty:
        out.append(("p", "No value is missing."))
    else:
        out.append(
            ("p", f"{len(result.missing)} value(s) could not be computed or were left out (policy: {plan.missing}):")
        )
        head = list(result.missing.columns)
        body = [["" if _isnan(v) else str(v) for v in row] for row in result.missing.itertuples(index=False)]
        out.append(("table", head, body))
    notes = result.tables.get("notes")
    if notes is not None and not notes.empty:
        out.append(("h", 2, "Notes"))
        out.append(("list", list(notes["note"])))
    return out


# ----------------------------------------------------------------------------------------------- HTML

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;margin:2em auto;max-width:1200px;
color:#222;line-height:1.4;padding:0 1em}
h1{font-size:1.6em;border-bottom:2px solid #0072B2}h2{font-size:1.3em;margin-top:1.6em;border-bottom:1px solid #ccc}
h3{font-size:1.05em;margin-top:1.3em}table{border-collapse:collapse;font-size:.82em;margin:.5em 0;display:block;
overflow-x:auto}th,td{border:1px solid #ddd;padding:3px 6px;text-align:left;vertical-align:top}
th{background:#f3f6fa}tr:nth-child(even) td{background:#fafafa}.alert{background:#fff3cd;border:1px solid #e0b000;
padding:.6em 1em;font-weight:600}figure{margin:1em 0}figure img{max-width:100%;border:1px solid #eee}
figcaption{font-size:.9em;color:#555}ul{font-size:.9em}
"""


def html(result: AnalysisResult, figures: Mapping[str, bytes], problems: Sequence[str]) -> str:
    """The self-contained HTML report."""
    return render_html(result.plan.title, blocks(result, list(figures), problems), figures)


def render_html(title: str, content: Sequence[Block], figures: Mapping[str, bytes] | None = None) -> str:
    """Blocks as a self-contained HTML page (figures embedded as PNG data)."""
    e = _html.escape
    parts = [
        "<!DOCTYPE html>",
        "<html lang='en'><head><meta charset='utf-8'>",
        f"<title>{e(title)}</title><style>{_CSS}</style></head><body>",
    ]
    for b in content:
        kind = b[0]
        if kind == "h":
            parts.append(f"<h{b[1]}>{e(str(b[2]))}</h{b[1]}>")
        elif kind == "p":
            parts.append(f"<p>{e(str(b[1]))}</p>")
        elif kind == "alert":
            parts.append(f"<p class='alert'>{e(str(b[1]))}</p>")
        elif kind == "list":
            parts.append("<ul>" + "".join(f"<li>{e(str(i))}</li>" for i in b[1]) + "</ul>")
        elif kind == "table":
            head = "".join(f"<th>{e(str(h))}</th>" for h in b[1])
            body = "".join("<tr>" + "".join(f"<td>{e(str(c))}</td>" for c in row) + "</tr>" for row in b[2])
            parts.append(f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>")
        elif kind == "figure":
            data = base64.b64encode((figures or {})[b[1]]).decode("ascii")
            parts.append(
                f"<figure id='{e(b[1])}'><img alt='{e(b[2])}' src='data:image/png;base64,{data}'>"
                f"<figcaption>{e(b[2])} [{e(b[1])}]</figcaption></figure>"
            )
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


# ------------------------------------------------------------------------------------------- Markdown


def _md_cell(c: Any) -> str:
    return str(c).replace("|", "\\|").replace("\n", " ")


def markdown(result: AnalysisResult, figure_files: Sequence[str], problems: Sequence[str]) -> str:
    """The report as Markdown; figures are linked from ``figures/``."""
    ids = [f.removesuffix(".png") for f in figure_files]
    return render_markdown(blocks(result, ids, problems))


def render_markdown(content: Sequence[Block]) -> str:
    """Blocks as Markdown (figures linked from ``figures/``)."""
    lines: list[str] = []
    for b in content:
        kind = b[0]
        if kind == "h":
            lines += ["#" * b[1] + " " + str(b[2]), ""]
        elif kind == "p":
            lines += [str(b[1]), ""]
        elif kind == "alert":
            lines += [f"> **{b[1]}**", ""]
        elif kind == "list":
            lines += [f"- {i}" for i in b[1]] + [""]
        elif kind == "table":
            lines.append("| " + " | ".join(_md_cell(h) for h in b[1]) + " |")
            lines.append("|" + "---|" * len(b[1]))
            lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in b[2]]
            lines.append("")
        elif kind == "figure":
            lines += [f"![{b[2]}](figures/{b[1]}.png)", "", f"*{b[2]}*", ""]
    return "\n".join(lines)


def summary(result: AnalysisResult, problems: Sequence[str]) -> dict[str, Any]:
    """Headline facts for scripts and the demo: counts, partial flag, problems, significant findings."""
    frame = result.to_frame()
    significant = frame[(frame["status"] == "ok") & (frame["significant"] == True)]  # noqa: E712
    return {
        "study": result.plan.study,
        "title": result.plan.title,
        "source": result.data.source,
        "data": dict(result.data.info),
        "partial": bool(result.partial or problems),
        "problems": list(problems),
        "tests": int(len(frame)),
        "not_computed": int((frame["status"] != "ok").sum()),
        "significant": [
            f"{r.test_id}/{r.metric}{f' [{r.split}]' if r.split else ''} {r.groups}" for r in significant.itertuples()
        ],
        "missing_values": int(len(result.missing)),
        "timings_s": dict(result.timings),
    }
