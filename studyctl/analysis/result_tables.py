"""The result tables beside the tests: units (what box plots show), cells, and pooled proportions."""

from __future__ import annotations

import math

import pandas as pd

from studyctl import stats
from studyctl.analysis.plan import AnalysisPlan
from studyctl.analysis.procedures import describe
from studyctl.analysis.shape import Prepared, unit_values
from studyctl.errors import StudyctlError

NAN = math.nan


def units_table(plan: AnalysisPlan, prep: Prepared) -> pd.DataFrame:
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


def cells_table(plan: AnalysisPlan, units: pd.DataFrame) -> pd.DataFrame:
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


def proportions_table(plan: AnalysisPlan, prep: Prepared) -> pd.DataFrame:
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
                    est, lo, hi = float(w.estimate), float(w.lower), float(w.upper)
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
