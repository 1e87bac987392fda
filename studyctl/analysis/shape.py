"""Shape the tidy metric table into the samples a test needs, applying the plan's missing-data policy.

Units of analysis: by default one value per participant × cell, where repetitions of a condition are
averaged (``aggregate: mean`` or ``median``) and a metric's sub-levels (tumour classes, nodules, items) are
averaged, or, for proportions, pooled by summing successes and chances. ``aggregate: none`` keeps
trials as units.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from studyctl.analysis.plan import AnalysisPlan
from studyctl.analysis.results import split_levels
from studyctl.analysis.table import MISSING_COLUMNS, MetricTable
from studyctl.errors import AnalysisError

KEY = ("participant", "group", "condition", "level")


def factor_column(factor: str) -> str:
    """Column of the tidy table holding a plan factor (a metric's own sub-level lives in ``level``)."""
    return factor if factor in ("condition", "group") else "level"


def row_units(units: pd.DataFrame, metric: str, split: str) -> pd.DataFrame:
    """The units one result row was computed from: ``units`` (the result's ``units`` table) of ``metric`` in the
    row's ``split`` cell (``"group=novice, condition=linear"``, as the runner writes it)."""
    sel = units[units["metric"] == metric]
    for factor, value in split_levels(split).items():
        sel = sel[sel[factor_column(factor)].astype(str) == value]
    return sel


@dataclass(frozen=True)
class Prepared:
    """The plan's view of the data: metric ids as in the plan, only planned conditions/groups."""

    frame: pd.DataFrame
    missing: pd.DataFrame
    problems: tuple[str, ...]
    notes: tuple[str, ...]


def prepare(plan: AnalysisPlan, table: MetricTable) -> Prepared:
    """Rename data metrics to plan ids, keep planned conditions and groups, apply the missing policy.

    Everything left out is counted in ``notes``/``problems``; nothing disappears without a line.
    """
    frame = table.frame
    problems: list[str] = []
    notes: list[str] = []
    missing = table.missing.copy()
    if frame.empty:
        raise AnalysisError(
            f"{table.source or 'the data'}: no metric values at all"
            + (f" ({table.info['empty_reason']})" if table.info.get("empty_reason") else "")
            + "; run sessions first (studyctl run or studyctl simulate) or check the data source"
        )
    parts = []
    for mid in plan.metrics:
        name = plan.metric_name(mid)
        # Database tables are computed per plan metric id; CSV tables carry the CSV's metric names.
        sel = frame[frame["metric"] == mid]
        if sel.empty and name != mid:
            sel = frame[frame["metric"] == name]
        if sel.empty:
            available = ", ".join(table.metrics()) or "none"
            problems.append(f"metric {mid!r} ({name}): no values in {table.source or 'the data'} (has: {available})")
            continue
        parts.append(sel.assign(metric=mid))
    if not parts:
        raise AnalysisError(f"{table.source or 'the data'}: none of the plan's metrics has values")
    out = pd.concat(parts, ignore_index=True)
    if not missing.empty:
        renamed = {plan.metric_name(m): m for m in plan.metrics}
        missing["metric"] = missing["metric"].map(lambda m: m if m in plan.metrics else renamed.get(m, m))

    planned = set(plan.condition_ids)
    extra = sorted(set(out["condition"].dropna()) - planned)
    for c in extra:
        n = int((out["condition"] == c).sum())
        notes.append(f"condition {c!r} is in the data but not in the plan: its {n} value(s) are not analysed")
    # Values tied to no condition (an end-of-study questionnaire) stay; tests comparing conditions skip them.
    out = out[out["condition"].isin(planned) | out["condition"].isna()]
    for c in plan.condition_ids:
        if not (out["condition"] == c).any():
            problems.append(f"condition {c!r}: no values in the data")
    if plan.groups:
        groups = set(plan.group_ids)
        has_group = out["group"].notna()
        stray = out[has_group & ~out["group"].isin(groups)]
        for g in sorted(set(stray["group"])):
            notes.append(
                f"group {g!r} is in the data but not in the plan: its values are only used where groups are pooled"
            )
    out, missing, extra_problems = _apply_missing_policy(plan, out, missing)
    problems.extend(extra_problems)
    return Prepared(out.reset_index(drop=True), missing, tuple(problems), tuple(notes))


def _apply_missing_policy(
    plan: AnalysisPlan, frame: pd.DataFrame, missing: pd.DataFrame
) -> tuple[pd.DataFrame, pd.DataFrame, list[str]]:
    problems: list[str] = []
    if frame["participant"].isna().all():
        return frame, missing, problems  # pooled counts: no participants to be complete or not
    added = []
    keep = []
    for mid, sel in frame.groupby("metric", sort=False):
        have = sel.groupby("participant")["condition"].agg(lambda s: set(s))
        lacking = {p: sorted(set(plan.condition_ids) - conds) for p, conds in have.items()}
        lacking = {p: c for p, c in lacking.items() if c}
        if lacking and plan.missing == "fail":
            first = ", ".join(f"{p} ({', '.join(c)})" for p, c in list(lacking.items())[:5])
            raise AnalysisError(
                f"metric {mid!r}: {len(lacking)} participant(s) lack values in some condition: {first}; the plan's "
                "missing policy is 'fail' (use 'available' or 'complete_cases' to analyse what exists)"
            )
        if lacking and plan.missing == "complete_cases":
            groups = sel.drop_duplicates("participant").set_index("participant")["group"]
            for p, conds in lacking.items():
                added.append(
                    {
                        "participant": p,
                        "group": groups.get(p),
                        "condition": ", ".join(conds),
                        "trial": None,
                        "metric": mid,
                        "reason": "complete_cases: participant dropped from this metric (no value in these conditions)",
                    }
                )
            sel = sel[~sel["participant"].isin(lacking)]
            problems.append(f"metric {mid!r}: {len(lacking)} participant(s) dropped (complete_cases)")
        keep.append(sel)
    frame = pd.concat(keep, ignore_index=True) if keep else frame.iloc[0:0]
    if added:
        missing = pd.concat([missing, pd.DataFrame(added, columns=list(MISSING_COLUMNS))], ignore_index=True)
    return frame, missing, problems


def unit_values(frame: pd.DataFrame, *, kind: str, keep: list[str], aggregate: str) -> pd.DataFrame:
    """One row per analysis unit with columns ``keep`` + participant (+ trial) + value, successes, chances.

    ``keep`` lists the tidy columns that stay separate (condition, group, level). For proportion metrics
    ``value`` is successes / chances after pooling; a unit with no chances gets NaN (and is dropped by the
    caller with a warning).
    """
    keys = ["participant", *[k for k in keep if k != "participant"]]
    if aggregate == "none" and kind != "proportion":
        keys = [*keys, "trial"]
    if kind == "proportion":
        g = frame.groupby(keys, dropna=False, sort=False)
        out = g.agg(
            successes=("value", "sum"), chances=("denominator", "sum"), n_trials=("value", "size")
        ).reset_index()
        with np.errstate(invalid="ignore", divide="ignore"):
            out["value"] = np.where(out["chances"] > 0, out["successes"] / out["chances"], np.nan)
        return out
    # Collapse repetitions first (within participant × condition × level), then the levels left out.
    fine = ["participant", "group", "condition", "level"] + (["trial"] if "trial" in keys else [])
    func = "median" if aggregate == "median" else "mean"
    first = frame.groupby(fine, dropna=False, sort=False)["value"].agg([func, "size"]).reset_index()
    first = first.rename(columns={func: "value", "size": "n_trials"})
    out = first.groupby(keys, dropna=False, sort=False).agg(value=("value", "mean"), n_trials=("n_trials", "sum"))
    out = out.reset_index()
    out["successes"] = np.nan
    out["chances"] = np.nan
    return out


def ordered_levels(values: pd.Series, preferred: list[str] | None) -> list[str]:
    """Levels present in ``values``: in ``preferred`` order when given, else in order of appearance."""
    present = list(dict.fromkeys(v for v in values if not (isinstance(v, float) and np.isnan(v)) and v is not None))
    if preferred:
        return [p for p in preferred if p in present]
    return present


def paired_pivot(sub: pd.DataFrame, col: str, levels: list[str]) -> tuple[np.ndarray, list[str]]:
    """Complete blocks by ``pivot_table`` (mean per participant × level; participants sorted; a participant
    with no value at all is not listed) and the participants left out."""
    wide = sub.pivot_table(index="participant", columns=col, values="value", aggfunc="mean")
    wide = wide.reindex(columns=levels)
    complete = wide.dropna()
    return complete.to_numpy(dtype=float), [str(p) for p in wide.index.difference(complete.index)]


class Blocks:
    """A cell's participants × levels table, built once, from which the complete blocks of any set of its
    levels are read (:meth:`matrix`): a post-hoc over k levels asks for k(k−1)/2 pairs of one cell.

    Where every participant × level has at most one unit (the usual case; a mean of one value is that value)
    the table is a plain array, without pandas' pivot machinery; otherwise each request goes to
    :func:`paired_pivot`. Either way a request gives what :func:`paired_pivot` gives."""

    def __init__(self, sub: pd.DataFrame, col: str) -> None:
        self.sub, self.col, self.wide = sub, col, None
        person = sub["participant"].to_numpy(dtype=object)
        level = sub[col].to_numpy(dtype=object)
        value = sub["value"].to_numpy(dtype=float)
        named = pd.notna(level)
        # strings only: pivot_table sorts numbers as numbers, np.unique of their text would not
        if not all(isinstance(v, str) for v in person) or not all(isinstance(v, str) for v in level[named]):
            return
        person, level, value = person[named], level[named], value[named]
        people, p_idx = np.unique(person, return_inverse=True)
        present, l_idx = np.unique(level, return_inverse=True)
        cell = p_idx * len(present) + l_idx
        if len(np.unique(cell)) != len(cell):  # repeated units: leave the means to pivot_table
            return
        wide = np.full((len(people), len(present)), np.nan)
        wide[p_idx, l_idx] = value
        self.people, self.wide = people, wide
        self.seen = ~np.isnan(wide).all(axis=1)  # pivot_table drops people with no value at all
        self.pos = {lv: j for j, lv in enumerate(present)}

    def matrix(self, levels: list[str]) -> tuple[np.ndarray, list[str]]:
        """The complete blocks of ``levels`` (participants sorted) and the participants left out."""
        if self.wide is None:
            return paired_pivot(self.sub, self.col, levels)
        missing = np.full(len(self.people), np.nan)
        cols = np.column_stack([self.wide[:, self.pos[lv]] if lv in self.pos else missing for lv in levels])
        complete = self.seen & ~np.isnan(cols).any(axis=1)
        return cols[complete], [str(p) for p in self.people[self.seen & ~complete]]


def paired_matrix(sub: pd.DataFrame, col: str, levels: list[str]) -> tuple[np.ndarray, list[str]]:
    """:func:`paired_pivot`'s matrix and list in a fraction of the time (a power analysis shapes thousands of
    these): :class:`Blocks` of the cell, read once."""
    return Blocks(sub, col).matrix(levels)


def pooled_counts(data: pd.DataFrame, keep: list[str]) -> pd.DataFrame:
    """Successes, chances and participants summed per ``keep`` group (counts pooled over participants)."""
    g = data.groupby(keep, dropna=False, sort=False)
    return g.agg(
        successes=("value", "sum"), chances=("denominator", "sum"), participants=("participant", "nunique")
    ).reset_index()
