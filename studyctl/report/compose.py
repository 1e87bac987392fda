"""Turn a plan's figure entry plus the analysis result into a matplotlib figure."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from studyctl.report import figures as F

if TYPE_CHECKING:
    from matplotlib.figure import Figure

    from studyctl.analysis.plan import FigureEntry
    from studyctl.analysis.results import AnalysisResult, FigureData


def _conditions(result: AnalysisResult, present: pd.Series | None = None) -> list[tuple[str, str]]:
    levels = [(c.id, c.display) for c in result.plan.condition_levels]
    if present is not None:
        have = set(present.dropna())
        levels = [(c, lbl) for c, lbl in levels if c in have]
    return levels


def draw_figure(result: AnalysisResult, spec: FigureEntry, data: FigureData | None) -> tuple[Figure, str]:
    """The figure for ``spec`` and a problem description ('' when it was drawn from real data)."""
    title = spec.title or spec.id
    try:
        drawer = _DRAWERS[spec.kind]
    except KeyError:
        return F.message_figure(f"unknown figure kind {spec.kind!r}", title=title), f"unknown kind {spec.kind!r}"
    return drawer(result, spec, data, title)


def _box(result: AnalysisResult, spec: FigureEntry, data: FigureData | None, title: str) -> tuple[Figure, str]:
    plan = result.plan
    units = result.tables.get("units", pd.DataFrame())
    tests = result.to_frame()
    panels = []
    missing = []
    for mid in spec.metrics:
        sel = units[units["metric"] == mid] if not units.empty else units
        if sel.empty:
            missing.append(mid)
        marks = tests[(tests["test_id"] == spec.marks) & (tests["metric"] == mid)] if spec.marks else None
        groups = [(g.id, g.display) for g in plan.group_levels] if "group" in spec.by and plan.groups else None
        panels.append(
            {
                "units": sel,
                "conditions": _conditions(result),
                "groups": groups,
                "label": plan.metric_label(mid),
                "unit": plan.metric_unit(mid),
                "marks": marks,
            }
        )
    fig = F.box_figure(panels, title=title)
    return fig, (f"no values for {', '.join(missing)}" if missing else "")


def _proportion(result: AnalysisResult, spec: FigureEntry, data: FigureData | None, title: str) -> tuple[Figure, str]:
    plan = result.plan
    props = result.tables.get("proportions", pd.DataFrame())
    mid = spec.metrics[0]
    sel = props[props["metric"] == mid] if not props.empty else props
    level_name = plan.metric_level(mid)
    by_level = level_name is not None and level_name in spec.by
    if sel.empty:
        return F.message_figure(f"no counts for {mid}", title=title), f"no counts for {mid}"
    levels = None
    if by_level:
        present = list(dict.fromkeys(sel["level"].dropna()))
        preferred = [str(x) for x in spec.options.get("levels", [])]
        levels = [x for x in preferred if x in present] + [x for x in present if x not in preferred]
        if not levels:
            by_level = False
    if not by_level:
        sel = sel[sel["level"].isna()]
    fig = F.proportion_figure(
        sel, conditions=_conditions(result, sel["condition"]), levels=levels, label=plan.metric_label(mid), title=title
    )
    return fig, ""


def _percent_change(
    result: AnalysisResult, spec: FigureEntry, data: FigureData | None, title: str
) -> tuple[Figure, str]:
    plan = result.plan
    pct = result.tables.get("percent_change", pd.DataFrame())
    test_id = spec.options.get("test")
    if not pct.empty and test_id:
        pct = pct[pct["test_id"] == test_id]
    if pct.empty:
        return F.message_figure("no percent-change table in this result", title=title), "no percent_change table"
    reference = str(pct["reference"].iloc[0])
    metrics = [(m, plan.metric_label(m)) for m in spec.metrics]
    return F.percent_change_figure(
        pct, metrics=metrics, conditions=_conditions(result), reference=reference, title=title
    ), ""


def _likert(result: AnalysisResult, spec: FigureEntry, data: FigureData | None, title: str) -> tuple[Figure, str]:
    answers = likert_answers(result, spec.metrics[0])
    if answers.empty:
        return F.message_figure("no Likert answers in this result", title=title), "no Likert answers"
    items = list(dict.fromkeys(answers["item"]))
    conds = [(c, lbl) for c, lbl in _conditions(result) if c in set(answers["level"])]
    points = int(spec.options.get("points", 5))
    return F.likert_figure(answers, items=items, conditions=conds, points=points, title=title), ""


def likert_answers(result: AnalysisResult, metric: str) -> pd.DataFrame:
    """Every answer of a Likert metric (item, condition as ``level``, value): the data of the stacked bars."""
    frame = result.data.frame
    if frame.empty:
        return pd.DataFrame(columns=["item", "level", "value"])
    # Database tables carry plan metric ids, CSV tables the built-in metric names (as analysis.shape reads them).
    sel = frame[frame["metric"] == metric]
    if sel.empty:
        sel = frame[frame["metric"] == result.plan.metric_name(metric)]
    if sel.empty:
        return pd.DataFrame(columns=["item", "level", "value"])
    return pd.DataFrame({"item": sel["level"].astype(str), "level": sel["condition"], "value": sel["value"]})


def likert_items_table(result: AnalysisResult, metric: str) -> pd.DataFrame:
    """Likert means per item (split ``item=…``) and the overall score (entries without an item split)."""
    lk = result.tables.get("likert", pd.DataFrame())
    if lk.empty:
        return lk
    lk = lk[lk["metric"] == metric].copy()
    lk["item"] = [
        s.split("=", 1)[1] if isinstance(s, str) and s.startswith("item=") else "overall" for s in lk["split"]
    ]
    # Items first, the overall score last (as the paper's Table 2).
    lk["_order"] = (lk["item"] == "overall").astype(int)
    return lk.sort_values("_order", kind="stable").drop(columns="_order")


def _trace(result: AnalysisResult, spec: FigureEntry, data: FigureData | None, title: str) -> tuple[Figure, str]:
    if data is None or data.frame is None or data.frame.empty:
        why = (
            data.problem
            if data is not None and data.problem
            else "no trace data was collected for this figure (it needs the study database's samples)"
        )
        return F.message_figure(why, title=title), why
    meta = dict(data.meta)
    panels = meta.get("panels") or list(dict.fromkeys(data.frame["panel"]))
    channels = [tuple(c) for c in meta.get("channels", [])]
    fig = F.trace_figure(
        data.frame,
        panels=panels,
        channels=channels,
        title=title,
        x_label=meta.get("x_label", "time (s)"),
        shade=meta.get("shade"),
        threshold=meta.get("threshold"),
    )
    return fig, data.problem


_DRAWERS = {
    "box": _box,
    "proportion": _proportion,
    "percent_change": _percent_change,
    "likert": _likert,
    "force_trace": _trace,
    "needle_force_profile": _trace,
    "controller_response": _trace,
}


def finite(x: float) -> bool:
    return x is not None and bool(np.isfinite(x))
