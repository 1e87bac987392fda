"""Metrics computed from what the study database holds: trials, events, samples, reports and answers.

Never from a participant's internals: a metric sees only what was recorded. Ground truth (tumour sites,
nodule centres, the planned needle path) comes from the scene as it was built for the trial: the
``scene_truth`` event when the engine recorded one, otherwise the scene plugin rebuilt from the stored
plan (scene spec, the trial's placement and its seeded scene stream).

Per-trial numbers come from the other packages' pure helpers where they exist
(:mod:`studyctl.models.needle_metrics`, :mod:`studyctl.models.palpation_metrics`); the matching of
reports to targets for the tissue studies is here.

Anything that cannot be computed becomes a row of ``missing`` with the reason: a planned trial that was
never run, an aborted trial without a completed repeat, a trial without samples, a ratio with no reports.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
import pandas as pd
from sqlalchemy import select

from studyctl.analysis.metric_defs import BUILTIN
from studyctl.analysis.plan import AnalysisPlan
from studyctl.analysis.table import COLUMNS, MISSING_COLUMNS, MetricTable, empty_frame
from studyctl.errors import AnalysisError, StudyctlError

# --------------------------------------------------------------------------------------- trial view


@dataclass
class TrialView:
    """Everything recorded about one completed trial, with samples and truth loaded on first use."""

    trial_id: int
    participant: str
    group: str | None
    condition: str
    repetition: int | None
    position: int
    time_limit_s: float | None
    outcome: Mapping[str, Any]
    placement: Mapping[str, Any]
    events: list[dict[str, Any]]
    reports: list[dict[str, Any]]
    session_seed: int
    plan: Any  # studyctl.engine.plan.SessionPlan
    protocol: Any  # studyctl.protocol.Protocol
    _load_samples: Callable[[int], pd.DataFrame] = field(repr=False, default=lambda _tid: pd.DataFrame())

    @cached_property
    def samples(self) -> pd.DataFrame:
        return self._load_samples(self.trial_id)

    @cached_property
    def truth(self) -> Mapping[str, Any]:
        for ev in self.events:
            if ev["kind"] in ("scene_truth", "truth"):
                return dict(ev.get("payload") or {})
        return rebuild_truth(self.plan, self.placement, self.session_seed, self.position)

    @property
    def duration_s(self) -> float:
        """The trial's duration: the loop's own end time, capped at the time limit."""
        d = self.outcome.get("duration_s")
        if d is None:
            for ev in self.events:
                if ev["kind"] == "trial_loop_end":
                    d = ev["t"]
        if d is None:
            raise AnalysisError("the trial recorded no duration")
        d = float(d)
        return min(d, float(self.time_limit_s)) if self.time_limit_s else d


_SCENES: dict[str, type] = {}  # scene classes by plugin name (entry-point lookups are slow)


def rebuild_truth(plan: Any, placement: Mapping[str, Any], seed: int, position: int) -> Mapping[str, Any]:
    """The scene's ground truth, rebuilt exactly as the engine built the scene for this trial."""
    from studyctl.engine.seeding import trial_streams
    from studyctl.plugins import registry

    if not plan.scene:
        raise AnalysisError("the study's plan names no scene, so there is no ground truth to score against")
    cls = _SCENES.get(plan.scene)
    if cls is None:
        cls = _SCENES[plan.scene] = registry.load_plugin("scene", plan.scene)
    scene = cls.build(plan.scene_spec, placement or {}, frozenset(), trial_streams(seed, position).scene)
    return scene.truth()


# ------------------------------------------------------------------------------------------ families
# Each returns rows (level, value, denominator) for one trial, or raises AnalysisError (→ missing).

Row = tuple[str | None, float, float]


def _needle(trial: TrialView, which: str) -> list[Row]:
    from studyctl.models.needle_metrics import needle_trial_metrics

    cache = trial.__dict__.setdefault("_needle_cache", {})
    if "m" not in cache:
        if trial.samples.empty:
            raise AnalysisError("no samples were recorded for this trial")
        events = [{"kind": e["kind"], "t": e["t"], **(e.get("payload") or {})} for e in trial.events]
        cache["m"] = needle_trial_metrics(
            trial.samples, events, trial.truth, time_limit_s=float(trial.time_limit_s or 90.0)
        )
    m = cache["m"]
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

    cache = trial.__dict__.setdefault("_tissue_cache", {})
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


def _grid_index(label: Any, labels: Sequence[str]) -> int:
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
            d = max(abs(col - tc), abs(row - tr))
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
    cache = trial.__dict__.setdefault("_contact_cache", {})
    if threshold not in cache:
        s = trial.samples
        mask = tumour_contact_mask(s, trial.truth, threshold)
        cache[threshold] = (s["t"].to_numpy(dtype=float), s["force_n"].to_numpy(dtype=float), mask)
    return cache[threshold]


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

# ------------------------------------------------------------------------------------------ loading


@dataclass
class _Loaded:
    trials: list[TrialView]
    missing: list[dict[str, Any]]
    responses: pd.DataFrame
    info: dict[str, Any]


def _load(store: Any, study: Any, protocol: Any) -> _Loaded:
    from studyctl.engine.plan import SessionPlan
    from studyctl.store.models import Event, LocationReport, Participant, Session, Trial

    missing: list[dict[str, Any]] = []
    with store.reading() as s:
        participants = list(
            s.scalars(select(Participant).where(Participant.study_id == study.id).order_by(Participant.id))
        )
        pids = [p.id for p in participants]
        sessions = (
            list(s.scalars(select(Session).where(Session.participant_id.in_(pids)).order_by(Session.id)))
            if pids
            else []
        )
        sids = [x.id for x in sessions]
        trials = list(s.scalars(select(Trial).where(Trial.session_id.in_(sids)).order_by(Trial.id))) if sids else []
        events = (
            s.execute(
                select(Event.session_id, Event.trial_id, Event.t_mono, Event.kind, Event.payload)
                .where(Event.session_id.in_(sids))
                .where((Event.trial_id.is_not(None)) | Event.kind.in_(("session_plan", "plan_amended")))
                .order_by(Event.session_id, Event.seq)
            ).all()
            if sids
            else []
        )
        tids = [t.id for t in trials]
        reports = (
            s.execute(
                select(LocationReport.trial_id, LocationReport.t, LocationReport.payload)
                .where(LocationReport.trial_id.in_(tids))
                .order_by(LocationReport.id)
            ).all()
            if tids
            else []
        )
    by_pid = {p.id: p for p in participants}
    plans: dict[int, Any] = {}
    trial_events: dict[int, list[dict[str, Any]]] = {}
    for sid, tid, t, kind, payload in events:
        if tid is None:
            plans[sid] = SessionPlan.from_json((payload or {})["plan"])  # the last (amended) plan wins
        else:
            trial_events.setdefault(tid, []).append({"kind": kind, "t": float(t), "payload": payload or {}})
    trial_reports: dict[int, list[dict[str, Any]]] = {}
    for tid, t, payload in reports:
        trial_reports.setdefault(tid, []).append({"t": float(t), **(payload or {})})
    session_of = {x.id: x for x in sessions}

    def group_of(p: Any) -> str | None:
        return p.group or p.stratum

    by_step: dict[tuple[int, int], list[Any]] = {}
    for tr in trials:
        step = int((tr.outcome or {}).get("step", tr.plan_position))
        by_step.setdefault((tr.participant_id, step), []).append(tr)
    views: list[TrialView] = []
    status_counts: dict[str, int] = {}
    for (pid, step), rows in by_step.items():
        p = by_pid[pid]
        for r in rows:
            status_counts[r.status] = status_counts.get(r.status, 0) + 1
        done = [r for r in rows if r.status == "completed"]
        if not done:
            last = rows[-1]
            why = {
                "planned": "planned but never run (session not finished)",
                "running": "interrupted while running (resume the session)",
            }.get(last.status, f"{last.status}: {last.invalid_reason or 'no reason recorded'}")
            missing.append(
                {
                    "participant": p.code,
                    "group": group_of(p),
                    "condition": last.condition,
                    "trial": str(last.id),
                    "metric": "*",
                    "reason": f"no completed trial at plan step {step}: {why}",
                }
            )
            continue
        tr = done[-1]
        sess = session_of[tr.session_id]
        views.append(
            TrialView(
                trial_id=tr.id,
                participant=p.code,
                group=group_of(p),
                condition=tr.condition,
                repetition=tr.repetition,
                position=step,
                time_limit_s=tr.time_limit_s,
                outcome=dict(tr.outcome or {}),
                placement=dict(tr.placement or {}),
                events=trial_events.get(tr.id, []),
                reports=trial_reports.get(tr.id, []),
                session_seed=int(sess.seed or 0),
                plan=plans.get(sess.id),
                protocol=protocol,
                _load_samples=store.read_samples,
            )
        )
    responses = _responses(store, participants, plans, by_pid)
    info = {
        "participants": len(participants),
        "sessions": len(sessions),
        "trials_completed": status_counts.get("completed", 0),
        "trials_other": {k: v for k, v in sorted(status_counts.items()) if k != "completed"},
    }
    return _Loaded(views, missing, responses, info)


def _responses(store: Any, participants: list, plans: Mapping[int, Any], by_pid: Mapping[int, Any]) -> pd.DataFrame:
    """Questionnaire answers with the condition they followed (None for end-of-study instruments)."""
    cols = ["participant", "group", "condition", "instrument", "item", "code", "session_id"]
    if not participants:
        return pd.DataFrame(columns=cols)
    frame = store.responses_frame()
    if frame.empty:
        return pd.DataFrame(columns=cols)
    frame = frame[frame["participant_id"].isin(list(by_pid))]
    rows = []
    for r in frame.itertuples(index=False):
        p = by_pid[r.participant_id]
        condition = None
        plan = plans.get(r.session_id)
        if plan is not None and isinstance(r.context, str) and r.context.startswith("step:"):
            try:
                condition = plan.step(int(r.context.split(":", 1)[1])).condition
            except StudyctlError:
                condition = None
        rows.append(
            {
                "participant": p.code,
                "group": p.group or p.stratum,
                "condition": condition,
                "instrument": r.instrument,
                "item": r.item,
                "code": float(r.code),
                "session_id": r.session_id,
            }
        )
    return pd.DataFrame(rows, columns=cols)


# ------------------------------------------------------------------------------------------ the table


def compute_metrics(
    plan: AnalysisPlan,
    store: Any,
    study: Any,
    *,
    on_progress: Callable[[int, int], None] | None = None,
) -> MetricTable:
    """Compute the plan's metrics for every completed trial of ``study``.

    Parameters
    ----------
    plan
        The analysis plan (its metrics and their parameters).
    store
        An open :class:`studyctl.store.StudyStore`.
    study
        The study row (``store.get_study(name)``).
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
    from studyctl.protocol import load_protocol_text

    protocol = (
        load_protocol_text(study.protocol_text, f"<protocol of study {study.name}>") if study.protocol_text else None
    )
    loaded = _load(store, study, protocol)
    source = f"{store.db.describe()} (study {study.name!r})" if hasattr(store, "db") else f"study {study.name!r}"
    rows: list[dict[str, Any]] = []
    missing = list(loaded.missing)
    trial_metrics = [m for m in plan.metrics if plan.metric_name(m) != "likert"]
    for i, trial in enumerate(loaded.trials):
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
        if on_progress is not None:
            on_progress(i + 1, len(loaded.trials))
    for mid in plan.metrics:
        if plan.metric_name(mid) != "likert":
            continue
        instrument = str(plan.metric_params(mid).get("instrument") or "")
        resp = loaded.responses
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
    info = dict(loaded.info)
    if not loaded.trials:
        other = info["trials_other"]
        info["empty_reason"] = (
            f"study {study.name!r} has no completed trials (trials by status: {other or 'none at all'})"
        )
        if frame.empty:
            raise AnalysisError(
                f"study {study.name!r} has no completed trials (trials by status: {other or 'none'}; "
                f"{info['participants']} participant(s)); run sessions first with studyctl run or studyctl simulate"
            )
    return MetricTable(
        frame=frame,
        missing=pd.DataFrame(missing, columns=list(MISSING_COLUMNS)),
        source=source,
        study=study.name,
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
    "rebuild_truth",
    "tumour_contact_mask",
]
