"""Metrics computed from what the study database holds: trials, events, samples, reports and answers.

Never from a participant's internals: a metric sees only what was recorded, through the analysis view of
the stored study (:mod:`studyctl.analysis.trials`, read by :class:`studyctl.store.reader.StudyReader`).
Ground truth (tumour sites, nodule centres, the planned needle path) follows the one rule of
:mod:`studyctl.analysis.truth`.

Per-trial numbers come from the other packages' pure helpers where they exist
(:mod:`studyctl.models.needle_metrics`, :mod:`studyctl.models.palpation_metrics`); the matching of
reports to targets for the tissue studies is here.

Anything that cannot be computed becomes a row of ``missing`` with the reason: a planned trial that was
never run, an aborted trial without a completed repeat, a trial without samples, a ratio with no reports.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from studyctl.analysis.metric_defs import BUILTIN
from studyctl.analysis.plan import AnalysisPlan
from studyctl.analysis.table import COLUMNS, MISSING_COLUMNS, MetricTable, empty_frame
from studyctl.analysis.trials import StoredStudy, TrialView
from studyctl.errors import AnalysisError, StudyctlError
from studyctl.models.grid_cells import cell_distance
from studyctl.store.reader import StudyReader
from studyctl.store.repository import StudyStore

if TYPE_CHECKING:
    from studyctl.store.models import Study

# ------------------------------------------------------------------------------------------ families
# Each returns rows (level, value, denominator) for one trial, or raises AnalysisError (→ missing).

Row = tuple[str | None, float, float]


def _needle(trial: TrialView, which: str) -> list[Row]:
    from studyctl.models.needle_metrics import needle_trial_metrics

    cache = trial.cache
    if "needle" not in cache:
        if trial.samples.empty:
            raise AnalysisError("no samples were recorded for this trial")
        events = [{"kind": e["kind"], "t": e["t"], **(e.get("payload") or {})} for e in trial.events]
        cache["needle"] = needle_trial_metrics(
            trial.samples, events, trial.truth, time_limit_s=float(trial.time_limit_s or 90.0)
        )
    m = cache["needle"]
    value = {
        "scans": m.scans,
        "duration": m.duration_s,
        "tracking_error": m.tracking_error_mm,
        "targeting_error": m.targeting_error_mm,
    }[which]
    if value is None or (isinstance(value, float) and math.isnan(value)):
        raise AnalysisError(f"{which} is undefined for this trial (the needle never entered the tissue)")
    return [(None, float(value), math.nan)]


def _scans(trial: TrialView, params: Mapping[str, Any]) -> list[Row]:
    n = sum(1 for e in trial.events if e["kind"] == "scan")
    return [(None, float(n), math.nan)]


def _time(trial: TrialView, params: Mapping[str, Any]) -> list[Row]:
    return [(None, trial.duration_s, math.nan)]


def _tissue(trial: TrialView, which: str, params: Mapping[str, Any]) -> list[Row]:
    """Seed 002/003 detection metrics through :func:`studyctl.models.palpation_metrics.score_trial`."""
    from studyctl.models.palpation_metrics import score_trial

    cache = trial.cache
    if "score" not in cache:
        radius = trial.protocol.trial.report.hit_radius if trial.protocol is not None else None
        if radius is None:
            raise AnalysisError("no hit radius: set trial.report.hit_radius in the protocol")
        reports = [r for r in trial.reports if "x_mm" in r and "y_mm" in r]
        cache["score"] = score_trial(reports, list(trial.truth.get("nodules") or []), float(radius), trial.duration_s)
    sc = cache["score"]
    if which == "sensitivity":
        return [(m.nodule, float(m.found), 1.0) for m in sc.per_nodule]
    if which == "ppv":
        return [(None, float(sc.hits), float(sc.reports))]
    if which == "nodules_found":
        return [(None, float(sc.nodules_found), math.nan)]
    if which == "false_reports":
        return [(None, float(sc.false_reports), math.nan)]
    raise AnalysisError(f"unknown tissue metric {which!r}")


def _grid_index(label: str | int, labels: Sequence[str]) -> int:
    """1-based index of a reported grid label ('3', 'C') on the plan's report grid."""
    text = str(label)
    if text in labels:
        return list(labels).index(text) + 1
    try:
        return int(text)
    except ValueError:
        raise AnalysisError(f"report names grid label {text!r}, not on the grid ({', '.join(labels)})") from None


def match_cells(
    reports: Sequence[tuple[int, int]], targets: Sequence[tuple[int, int]], tolerance: float
) -> tuple[list[bool], list[int]]:
    """Greedy one-to-one matching of grid reports to target cells (Chebyshev distance ≤ ``tolerance``).

    Each report claims the nearest target not claimed before (ties: the earlier target). Returns
    (found flag per target, 1/0 per report).
    """
    found = [False] * len(targets)
    hits = []
    for col, row in reports:
        best, best_d = None, math.inf
        for i, (tc, tr) in enumerate(targets):
            d = cell_distance((col, row), (tc, tr))
            if not found[i] and d <= tolerance and d < best_d:
                best, best_d = i, d
        if best is None:
            hits.append(0)
        else:
            found[best] = True
            hits.append(1)
    return found, hits


def _palpation_reports(trial: TrialView, tolerance: float) -> tuple[list[dict[str, Any]], list[bool], list[int]]:
    tumours = list(trial.truth.get("tumours") or [])
    if not tumours:
        raise AnalysisError("the scene truth lists no tumours")
    cols = trial.plan.report.columns if trial.plan is not None else ()
    rows = trial.plan.report.rows if trial.plan is not None else ()
    reports = [
        (_grid_index(r["column"], cols), _grid_index(r["row"], rows))
        for r in trial.reports
        if "column" in r and "row" in r
    ]
    found, hits = match_cells(reports, [(int(t["col"]), int(t["row"])) for t in tumours], tolerance)
    return tumours, found, hits


def tumour_contact_mask(samples: pd.DataFrame, truth: Mapping[str, Any], threshold: float) -> np.ndarray:
    """Samples in tumour contact: probe footprint over a tumour and sensor force above ``threshold``.

    "Over a tumour" is the sponge scene's rule (:func:`studyctl.scenes.sponge.tumour_under_probe`: centre
    distance ≤ tumour radius + probe radius), evaluated for all samples at once.
    """
    need = ("t", "force_n", "probe_x_mm", "probe_y_mm")
    if samples.empty or any(c not in samples for c in need):
        raise AnalysisError(f"the trial's samples lack {', '.join(c for c in need if c not in samples) or 'rows'}")
    f = samples["force_n"].to_numpy(dtype=float)
    x = samples["probe_x_mm"].to_numpy(dtype=float)
    y = samples["probe_y_mm"].to_numpy(dtype=float)
    reach = float(truth.get("probe_radius_mm", 0.0))
    over = np.zeros(len(samples), dtype=bool)
    for tum in truth.get("tumours", ()):
        over |= np.hypot(x - float(tum["x_mm"]), y - float(tum["y_mm"])) <= float(tum["radius_mm"]) + reach
    return over & np.isfinite(f) & (f > threshold)


def _contact(trial: TrialView, threshold: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample times, forces and the tumour-contact mask of a trial (cached per threshold)."""
    key = f"contact@{threshold!r}"
    if key not in trial.cache:
        s = trial.samples
        mask = tumour_contact_mask(s, trial.truth, threshold)
        trial.cache[key] = (s["t"].to_numpy(dtype=float), s["force_n"].to_numpy(dtype=float), mask)
    return trial.cache[key]


def _palpation(trial: TrialView, which: str, params: Mapping[str, Any]) -> list[Row]:
    if which in ("localisation_accuracy", "detection"):
        tumours, found, hits = _palpation_reports(trial, float(params.get("tolerance_cells", 1)))
        if which == "detection":
            return [(str(t["class"]), float(f), 1.0) for t, f in zip(tumours, found, strict=True)]
        if not hits:
            raise AnalysisError("no reports in this trial: localising accuracy (correct / reports) is undefined")
        return [(None, sum(hits) / len(hits), math.nan)]
    t, f, contact = _contact(trial, float(params.get("threshold_n", 0.5)))
    if which == "tumour_contact_time":
        dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if len(t) > 1 else 0.0))
        return [(None, float(dt[contact].sum()), math.nan)]
    if not contact.any():
        raise AnalysisError("the probe never pressed on a tumour above the threshold: mean contact force undefined")
    return [(None, float(f[contact].mean()), math.nan)]


FAMILIES: dict[str, Callable[[TrialView, Mapping[str, Any]], list[Row]]] = {
    "scans": _scans,
    "duration": lambda t, p: _needle(t, "duration"),
    "tracking_error": lambda t, p: _needle(t, "tracking_error"),
    "targeting_error": lambda t, p: _needle(t, "targeting_error"),
    "completion_time": _time,
    "detection_time": _time,
    "sensitivity": lambda t, p: _tissue(t, "sensitivity", p),
    "ppv": lambda t, p: _tissue(t, "ppv", p),
    "nodules_found": lambda t, p: _tissue(t, "nodules_found", p),
    "false_reports": lambda t, p: _tissue(t, "false_reports", p),
    "localisation_accuracy": lambda t, p: _palpation(t, "localisation_accuracy", p),
    "detection": lambda t, p: _palpation(t, "detection", p),
    "mean_contact_force": lambda t, p: _palpation(t, "mean_contact_force", p),
    "tumour_contact_time": lambda t, p: _palpation(t, "tumour_contact_time", p),
}

# ------------------------------------------------------------------------------------------ the table


def compute_metrics(
    plan: AnalysisPlan,
    source: StoredStudy | StudyReader | StudyStore,
    study: str | Study | None = None,
    *,
    on_progress: Callable[[int, int], None] | None = None,
) -> MetricTable:
    """Compute the plan's metrics for every completed trial of a stored study.

    Parameters
    ----------
    plan
        The analysis plan (its metrics and their parameters).
    source
        The study as analysis sees it (:class:`~studyctl.analysis.trials.StoredStudy`, shared with trace
        figures), a :class:`~studyctl.store.reader.StudyReader`, or an open store with ``study`` (its row
        or name; None: the database's only study).
    on_progress
        Called with (trials done, trials total).

    Returns
    -------
    MetricTable
        Values keyed by the plan's metric ids; ``missing`` lists every trial or value that could not be
        used and why.

    Raises
    ------
    AnalysisError
        When the study has no completed trial at all (with what the trials' statuses are).
    """
    if isinstance(source, StudyStore):
        source = StudyReader(source, study)
    stored = source if isinstance(source, StoredStudy) else StoredStudy(source)
    rows: list[dict[str, Any]] = []
    missing = list(stored.missing)
    trial_metrics = [m for m in plan.metrics if plan.metric_name(m) != "likert"]
    trials = stored.trials
    for i, trial in enumerate(trials):
        for mid in trial_metrics:
            name = plan.metric_name(mid)
            func = FAMILIES.get(name)
            base = {
                "participant": trial.participant,
                "group": trial.group,
                "condition": trial.condition,
                "trial": str(trial.trial_id),
                "repetition": trial.repetition,
                "metric": mid,
            }
            if func is None:
                missing.append({**_miss(base), "reason": f"no computation for metric {name!r}"})
                continue
            try:
                for level, value, denom in func(trial, plan.metric_params(mid)):
                    rows.append({**base, "level": level, "value": value, "denominator": denom})
            except (StudyctlError, KeyError, ValueError) as exc:
                missing.append({**_miss(base), "reason": str(exc)})
        trial.release_samples()  # what the metrics needed is in the trial's cache; keep memory flat
        if on_progress is not None:
            on_progress(i + 1, len(trials))
    for mid in plan.metrics:
        if plan.metric_name(mid) != "likert":
            continue
        instrument = str(plan.metric_params(mid).get("instrument") or "")
        resp = stored.responses
        if instrument:
            resp = resp[resp["instrument"] == instrument]
        for r in resp.itertuples(index=False):
            rows.append(
                {
                    "participant": r.participant,
                    "group": r.group,
                    "condition": r.condition,
                    "trial": None,
                    "repetition": None,
                    "metric": mid,
                    "level": r.item,
                    "value": r.code,
                    "denominator": math.nan,
                }
            )
    frame = pd.DataFrame(rows, columns=list(COLUMNS)) if rows else empty_frame()
    info = stored.info
    name = stored.name
    if not trials:
        other = info["trials_other"]
        info["empty_reason"] = (
            f"study {name!r} has no completed trials (trials by status: {other or 'none at all'})"
        )
        if frame.empty:
            raise AnalysisError(
                f"study {name!r} has no completed trials (trials by status: {other or 'none'}; "
                f"{info['participants']} participant(s)); run sessions first with studyctl run or studyctl simulate"
            )
    return MetricTable(
        frame=frame,
        missing=pd.DataFrame(missing, columns=list(MISSING_COLUMNS)),
        source=stored.reader.source,
        study=name,
        info=info,
    )


def _miss(base: Mapping[str, Any]) -> dict[str, Any]:
    return {k: base.get(k) for k in MISSING_COLUMNS if k != "reason"}


def known_metrics() -> list[str]:
    """Built-in metrics that have a computation (all of :data:`BUILTIN`)."""
    return [m for m in BUILTIN if m in FAMILIES or m == "likert"]


__all__ = [
    "FAMILIES",
    "TrialView",
    "compute_metrics",
    "known_metrics",
    "match_cells",
    "tumour_contact_mask",
]
