"""The simulated counterpart of each published target, computed from a study's metric table and test rows.

Pure computation: it takes the analysis layer's tidy frames (:class:`~studyctl.analysis.MetricTable` ``frame``
and :meth:`~studyctl.analysis.AnalysisResult.to_frame`) and returns a frozen result. Statistics are over
participants (``unit: participant``, the default): each person's trials are averaged first (a proportion
pools successes over trials), then the mean / SD / CV (SD / mean) / median / IQR / pooled proportion is taken
across people,
as the papers report between-subject figures. Intervals are 95 % percentile bootstraps over participants
(the passed seeded Generator). ``count_total`` is scaled to the paper's n when the target gives one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from studyctl.analysis.shape import factor_column
from studyctl.errors import UnknownKeyError, UsageError
from studyctl.populations.targets import Target

BOOTSTRAP = 400
COLUMNS = ("target", "statistic", "value", "low", "high", "se", "participants", "note", "higher")


@dataclass(frozen=True)
class SimulatedValue:
    """One target's simulated value (a bool for verdicts; NaN when the study has no data for it)."""

    target: str
    statistic: str
    value: float | bool
    low: float = math.nan
    high: float = math.nan
    se: float = math.nan
    participants: int = 0
    note: str = ""
    higher: str = ""  # a pair target with a stated direction: the level the simulated people scored higher on


@dataclass(frozen=True)
class SimulatedStats:
    values: tuple[SimulatedValue, ...]

    def get(self, target_id: str) -> SimulatedValue:
        for v in self.values:
            if v.target == target_id:
                return v
        raise UnknownKeyError(f"no simulated value for target {target_id!r}")

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame([[getattr(v, c) for c in COLUMNS] for v in self.values], columns=list(COLUMNS))


def _filter(frame: pd.DataFrame, target: Target, *, drop: Sequence[str] = ()) -> pd.DataFrame:
    f = frame[frame["metric"] == target.metric]
    for col, val in target.filters().items():
        if col in drop:
            continue
        f = f[f[col].astype(str) == val]
    return f


def _per_person(f: pd.DataFrame, statistic: str) -> pd.DataFrame:
    """One row per participant: ``num`` and ``den`` (a proportion's successes and trials; else mean, 1)."""
    if f.empty:
        return pd.DataFrame(columns=["participant", "num", "den"])
    den = f["denominator"].astype(float)
    if statistic == "proportion" and den.notna().all() and (den > 0).all():
        g = f.assign(num=f["value"].astype(float) * den, den=den).groupby("participant")[["num", "den"]].sum()
    elif statistic == "count_total":
        g = f.groupby("participant")["value"].sum().to_frame("num").assign(den=1.0)
    else:
        g = f.groupby("participant")["value"].mean().to_frame("num").assign(den=1.0)
    return g.reset_index()


def _stat(num: np.ndarray, den: np.ndarray, statistic: str, scale: float) -> float:
    if len(num) == 0:
        return math.nan
    x = num / den
    if statistic == "mean":
        return float(np.mean(x))
    if statistic == "sd":
        return float(np.std(x, ddof=1)) if len(x) > 1 else math.nan
    if statistic == "cv":  # between-person SD relative to the mean
        m = float(np.mean(x))
        return float(np.std(x, ddof=1)) / abs(m) if len(x) > 1 and m else math.nan
    if statistic == "median":
        return float(np.median(x))
    if statistic == "iqr":
        q1, q3 = np.percentile(x, [25, 75])
        return float(q3 - q1)
    if statistic == "proportion":
        return float(np.sum(num) / np.sum(den))
    if statistic == "count_total":
        return float(np.sum(num) * scale)
    raise UsageError(f"unknown statistic {statistic!r}")


def _bootstrap(fn, n: int, rng: np.random.Generator) -> tuple[float, float, float]:  # noqa: ANN001
    if n < 2:
        return math.nan, math.nan, math.nan
    draws = np.array([fn(rng.integers(0, n, n)) for _ in range(BOOTSTRAP)], dtype=float)
    draws = draws[np.isfinite(draws)]
    if len(draws) < 10:
        return math.nan, math.nan, math.nan
    lo, hi = np.percentile(draws, [2.5, 97.5])
    return float(lo), float(hi), float(np.std(draws, ddof=1))


def _descriptive(frame: pd.DataFrame, t: Target, rng: np.random.Generator) -> SimulatedValue:
    f = _filter(frame, t)
    if t.unit == "trial":
        f = f.assign(participant=np.arange(len(f)).astype(str))  # every trial its own unit
    pp = _per_person(f, t.statistic)
    n = len(pp)
    if n == 0:
        return SimulatedValue(t.id, t.statistic, math.nan, note=f"no simulated {t.metric} rows for {t.where or 'all'}")
    people = pp["participant"].nunique()
    n_pub = t.uncertainty.get("n")
    scale = float(n_pub) / people if (t.statistic == "count_total" and n_pub) else 1.0
    num, den = pp["num"].to_numpy(float), pp["den"].to_numpy(float)
    value = _stat(num, den, t.statistic, scale)
    lo, hi, se = _bootstrap(lambda i: _stat(num[i], den[i], t.statistic, scale), n, rng)
    note = f"scaled to the paper's n = {n_pub:g}" if scale != 1.0 else ""
    return SimulatedValue(t.id, t.statistic, value, lo, hi, se, people, note)


def _pct_change(frame: pd.DataFrame, t: Target, rng: np.random.Generator) -> SimulatedValue:
    f = _filter(frame, t, drop=("condition",))
    cond = t.filters()["condition"]
    per = f.groupby(["participant", "condition"])["value"].mean().unstack("condition")
    if cond not in per or t.baseline not in per:
        return SimulatedValue(t.id, t.statistic, math.nan, note=f"no simulated {t.metric} for {cond} and {t.baseline}")
    a, b = per[cond].to_numpy(float), per[t.baseline].to_numpy(float)

    def fn(i: np.ndarray) -> float:
        ma, mb = np.nanmean(a[i]), np.nanmean(b[i])
        return 100.0 * (ma - mb) / mb if mb else math.nan

    n = len(per)
    value = fn(np.arange(n))
    lo, hi, se = _bootstrap(fn, n, rng)
    return SimulatedValue(t.id, t.statistic, value, lo, hi, se, n)


def _test_row(tests: pd.DataFrame, t: Target) -> pd.Series | None:
    """The plan's result row a test target compares with: the omnibus / two-sample row of its test, or with
    ``pair`` the pairwise (or post-hoc) row of those two levels, written in either order."""
    rows = tests[(tests["metric"] == t.metric) & ((tests["test_id"] == t.test) | (tests["test"] == t.test))]
    for col, val in t.where.items():
        rows = rows[rows["split"].fillna("").astype(str).str.contains(f"{col}={val}", regex=False)]
    if t.pair:
        a, b = t.pair
        rows = rows[rows["kind"].isin(["pairwise", "posthoc", "two_sample"])
                    & rows["groups"].fillna("").astype(str).isin([f"{a} vs {b}", f"{b} vs {a}"])]
    else:
        rows = rows[rows["kind"].isin(["omnibus", "two_sample", "pairwise"])]
    if rows.empty:
        return None
    order = {"omnibus": 0, "two_sample": 1, "pairwise": 2, "posthoc": 3}
    return rows.assign(_o=rows["kind"].map(order)).sort_values("_o").iloc[0]


def _verdict(row: pd.Series, alpha: float) -> bool | None:
    """Significant? The plan's own decision where the row carries one at this alpha (a Newcombe margin, W against
    its critical value, an adjusted post-hoc p); else p < alpha."""
    sig = row.get("significant")
    row_alpha = row.get("alpha")
    if isinstance(sig, bool | np.bool_) and (row_alpha is None or pd.isna(row_alpha)
                                             or math.isclose(float(row_alpha), alpha)):
        return bool(sig)
    p = row.get("p")
    return None if p is None or pd.isna(p) else bool(float(p) < alpha)


def _higher(metrics: pd.DataFrame, t: Target, compare: str) -> str:
    """Which level of ``t.pair`` the simulated people scored higher on: per person (a proportion pooled over their
    trials, else their mean), then the sign of P(a > b) − P(a < b) over every pair of people (the direction a rank
    test measures; for 0/1 data the larger proportion). '' when tied or without data."""
    if metrics.empty or "metric" not in metrics:
        return ""
    f = _filter(metrics, t)
    # the compared factor's column (a row may not name it): the first that holds both levels
    cols = [c for c in dict.fromkeys([factor_column(compare or "condition"), "condition", "group", "level"])
            if c in f and set(t.pair) <= set(f[c].astype(str))]
    if not cols:
        return ""
    col = cols[0]
    values = []
    for level in t.pair:
        pp = _per_person(f[f[col].astype(str) == level], "proportion")
        values.append(pp["num"].to_numpy(float) / pp["den"].to_numpy(float))
    a, b = values
    if len(a) == 0 or len(b) == 0:
        return ""
    score = float(np.sign(a[:, None] - b[None, :]).sum())
    return t.pair[0] if score > 0 else t.pair[1] if score < 0 else ""


def _test(tests: pd.DataFrame, t: Target, alpha: float, metrics: pd.DataFrame | None = None) -> SimulatedValue:
    row = _test_row(tests, t)
    what = f"{t.test} on {t.metric}" + (f" ({t.pair[0]} vs {t.pair[1]})" if t.pair else "")
    if row is None and t.pair and t.statistic == "verdict":
        omnibus = _test_row(tests, Target(t.id, t.metric, t.statistic, t.value, t.role, t.where, test=t.test))
        if omnibus is not None and omnibus.get("status") in (None, "ok") and omnibus.get("kind") == "omnibus" \
                and _verdict(omnibus, alpha) is False:
            # post-hoc pairs run only after a significant omnibus test: this pair is not significant
            higher = _higher(metrics, t, str(omnibus.get("compare") or "")) if t.higher and metrics is not None \
                else ""
            return SimulatedValue(t.id, t.statistic, False, participants=int(omnibus.get("n") or 0),
                                  note=f"no post-hoc: the omnibus {omnibus.get('test')} is not significant (p = "
                                       f"{float(omnibus['p']):.3g})", higher=higher)
    if row is None or row.get("status") not in (None, "ok"):
        why = "no such test row" if row is None else f"test status {row.get('status')}"
        return SimulatedValue(t.id, t.statistic, math.nan, note=f"{why} for {what}")
    p = float(row["p"]) if pd.notna(row.get("p")) else math.nan
    n = int(row["n"]) if "n" in row and pd.notna(row["n"]) else 0
    higher = _higher(metrics, t, str(row.get("compare") or "")) if t.higher and metrics is not None else ""
    if t.statistic == "test_p":
        if not math.isfinite(p):
            return SimulatedValue(t.id, t.statistic, math.nan, note=f"no p-value for {what}")
        return SimulatedValue(t.id, t.statistic, p, participants=n, note=str(row.get("groups") or ""), higher=higher)
    verdict = _verdict(row, alpha)
    if verdict is None:
        return SimulatedValue(t.id, t.statistic, math.nan, note=f"no verdict for {what}")
    if math.isfinite(p):
        how = f"p = {p:.3g}"
    elif pd.notna(row.get("statistic")):
        how = f"{row.get('statistic_name') or row.get('test')} = {float(row['statistic']):.3g}"
    else:
        how = f"{row.get('test')}: {'significant' if verdict else 'not significant'}"
    if t.higher:
        how += f"; {higher} higher" if higher else "; no difference in direction"
    return SimulatedValue(t.id, t.statistic, verdict, participants=n, note=how, higher=higher)


def simulated_values(targets: Sequence[Target], metrics: pd.DataFrame, tests: pd.DataFrame, *, alpha: float,
                     rng: np.random.Generator) -> SimulatedStats:
    """The simulated value (with a bootstrap interval) of every target.

    Parameters
    ----------
    targets
        The published targets.
    metrics
        A metric table's ``frame`` (participant, group, condition, trial, …, metric, level, value, denominator).
    tests
        The plan's result rows (``AnalysisResult.to_frame()``; columns test_id, kind, metric, test, split, p …).
    alpha
        Significance level of the verdicts.
    rng
        Seeded Generator for the bootstrap.
    """
    out = []
    for t in targets:
        if t.is_test:
            out.append(_test(tests, t, alpha, metrics))
        elif t.statistic == "pct_change_vs_baseline":
            out.append(_pct_change(metrics, t, rng))
        else:
            out.append(_descriptive(metrics, t, rng))
    return SimulatedStats(tuple(out))


def stats_from_frame(frame: pd.DataFrame | list[dict]) -> SimulatedStats:
    """:class:`SimulatedStats` back from its ``to_frame()`` (or the frame's JSON records, e.g. from a journal)."""
    records = frame.to_dict("records") if isinstance(frame, pd.DataFrame) else list(frame)
    out = []
    for r in records:
        v = r.get("value")
        if v is None or (isinstance(v, float) and math.isnan(v)):
            v = math.nan
        elif not isinstance(v, bool):
            v = float(v)
        num = {k: (math.nan if r.get(k) is None else float(r[k])) for k in ("low", "high", "se")}
        higher = r.get("higher")
        out.append(SimulatedValue(str(r["target"]), str(r["statistic"]), v, participants=int(r.get("participants")
                                  or 0), note=str(r.get("note") or ""),
                                  higher="" if higher is None or (isinstance(higher, float) and math.isnan(higher))
                                  else str(higher), **num))
    return SimulatedStats(tuple(out))
