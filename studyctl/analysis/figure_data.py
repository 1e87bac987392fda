"""Data for the figures that show signals rather than statistics.

* ``force_trace`` (seed 000 Fig. 6): sensor force and actuator commands around the first tumour contact
  of one stored trial per condition.
* ``needle_force_profile`` (seed 001 Fig. 3): the axial needle force (the logged device force projected on
  the needle axis) against insertion depth for one stored trial per condition.
* ``controller_response`` (seed 000 Fig. 4): the outputs of every condition's controller for trapezoidal
  force waves of different ramp rates and plateaus. These are model curves: the controllers are run on
  synthetic inputs, exactly as the paper characterised them.

Each collector returns a :class:`~studyctl.analysis.results.FigureData`; when something is missing the
``problem`` says what, and the report draws a notice instead of a silent gap.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from studyctl.analysis.plan import AnalysisPlan, FigureEntry
from studyctl.analysis.results import FigureData
from studyctl.errors import StudyctlError

FORCE = "force_n"
COMMANDS = (("balloon_pct", "balloon (%)"), ("vibration_pct", "vibration (%)"))


def trapezoid_waves(
    rate_hz: float, waves: Sequence[tuple[float, float, float]] | None = None, gap_s: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Time and force of consecutive trapezoids (ramp s, plateau N, hold s) separated by ``gap_s`` of zero."""
    waves = waves or ((1.0, 1.0, 2.0), (1.0, 2.0, 2.0), (0.25, 2.0, 2.0))
    pieces = [np.zeros(int(gap_s * rate_hz))]
    for ramp, level, hold in waves:
        n_r = max(1, int(round(ramp * rate_hz)))
        n_h = max(1, int(round(hold * rate_hz)))
        up = np.linspace(0.0, level, n_r, endpoint=False)
        pieces += [up, np.full(n_h, level), up[::-1] + level / n_r, np.zeros(int(gap_s * rate_hz))]
    force = np.concatenate(pieces)
    return np.arange(len(force)) / rate_hz, force


def controller_response(
    protocol: Any, *, conditions: Sequence[str] | None = None, waves: Sequence[tuple[float, float, float]] | None = None
) -> FigureData:
    """Run each condition's controller on trapezoidal force waves; channels force and both commands."""
    from studyctl.plugins import registry
    from studyctl.plugins.interfaces import Observation

    frames = []
    panels = []
    problems = []
    for cond in protocol.conditions:
        if conditions and cond.id not in conditions:
            continue
        if cond.controller is None or cond.manual:
            continue
        try:
            cls = registry.load_plugin("controller", cond.controller)
            ctrl = cls(dict(cond.params), None)
        except StudyctlError as exc:
            problems.append(f"{cond.id}: {exc}")
            continue
        rate = float(getattr(ctrl, "rate_hz", 50.0) or 50.0)
        t, force = trapezoid_waves(rate, waves)
        ctrl.reset()
        out = {name: np.empty(len(t)) for name, _ in COMMANDS}
        for i, (ti, fi) in enumerate(zip(t, force, strict=True)):
            cmd = ctrl.step(Observation(float(ti), {FORCE: float(fi)}))
            for name, _ in COMMANDS:
                out[name][i] = float(cmd.get(name, 0.0))
        label = cond.label or cond.id
        panels.append(label)
        frames.append(pd.DataFrame({"panel": label, "x": t, FORCE: force, **out}))
    if not frames:
        return FigureData(pd.DataFrame(), problem="no condition of this protocol runs a palpation controller")
    return FigureData(
        pd.concat(frames, ignore_index=True),
        meta={
            "panels": panels,
            "x_label": "time (s)",
            "channels": [(FORCE, "sensor force (N)", "left"), *[(c, lbl, "right") for c, lbl in COMMANDS]],
        },
        problem="; ".join(problems),
    )


def _first_trials(store: Any, study: Any, conditions: Sequence[str]) -> dict[str, int]:
    """The first completed trial (by id) of each condition."""
    from sqlalchemy import select

    from studyctl.store.models import Participant, Session, Trial

    with store.reading() as s:
        rows = s.execute(
            select(Trial.condition, Trial.id)
            .join(Session, Session.id == Trial.session_id)
            .join(Participant, Participant.id == Session.participant_id)
            .where(Participant.study_id == study.id, Trial.status == "completed", Trial.condition.in_(conditions))
            .order_by(Trial.id)
        ).all()
    out: dict[str, int] = {}
    for cond, tid in rows:
        out.setdefault(cond, int(tid))
    return out


def _per_condition(
    plan: AnalysisPlan,
    store: Any,
    study: Any,
    conds: Sequence[str],
    panel: Callable[[str, int], pd.DataFrame | str],
    meta: dict[str, Any],
) -> FigureData:
    """One panel per condition, from its first completed trial.

    ``panel(condition, trial_id)`` returns the panel's frame, or the text of why it cannot be drawn (the
    figure's ``problem`` lists those after the condition). Panels are labelled with the plan's condition
    labels; ``meta`` is added after ``panels``.
    """
    trials = _first_trials(store, study, conds)
    labels = {c.id: c.display for c in plan.condition_levels}
    frames, panels, problems = [], [], []
    for cond in conds:
        if cond not in trials:
            problems.append(f"{cond}: no completed trial")
            continue
        frame = panel(cond, trials[cond])
        if isinstance(frame, str):
            problems.append(f"{cond}: {frame}")
            continue
        frame.insert(0, "panel", labels.get(cond, cond))
        frames.append(frame)
        panels.append(labels.get(cond, cond))
    if not frames:
        return FigureData(pd.DataFrame(), problem="; ".join(problems) or "no samples")
    frame = pd.concat(frames, ignore_index=True)
    return FigureData(frame, meta={"panels": panels, **meta}, problem="; ".join(problems))


def force_trace(plan: AnalysisPlan, store: Any, study: Any, spec: FigureEntry) -> FigureData:
    """Force and commands ±``window_s`` around the first tumour contact of one trial per condition.

    Tumour contact is what the contact metrics use (:func:`studyctl.analysis.metrics.tumour_contact_mask`):
    the probe over a tumour with the force above the threshold; those spans are shaded.
    """
    from studyctl.analysis.metrics import tumour_contact_mask

    threshold = float(spec.options.get("threshold_n", _contact_threshold(plan)))
    window = float(spec.options.get("window_s", 3.0))

    def panel(cond: str, tid: int) -> pd.DataFrame | str:
        samples = store.read_samples(tid)
        try:
            contact = tumour_contact_mask(samples, _trial_truth(store, tid), threshold)
        except StudyctlError as exc:
            return f"trial {tid}: {exc}"
        t = samples["t"].to_numpy(dtype=float)
        f = samples[FORCE].to_numpy(dtype=float)
        if not contact.any():
            return f"trial {tid} never pressed on a tumour above {threshold:g} N"
        centre = t[np.flatnonzero(contact)[0]]
        sel = (t >= centre - window) & (t <= centre + window)
        frame = pd.DataFrame({"x": t[sel] - centre, FORCE: f[sel], "contact": contact[sel]})
        for name, _ in COMMANDS:
            frame[name] = samples[name].to_numpy(dtype=float)[sel] if name in samples else np.nan
        return frame

    conds = list(spec.options.get("conditions") or plan.condition_ids)
    meta = {
        "x_label": "time from the first tumour contact (s)",
        "shade": "contact",
        "threshold": threshold,
        "channels": [(FORCE, "sensor force (N)", "left"), *[(c, lbl, "right") for c, lbl in COMMANDS]],
    }
    return _per_condition(plan, store, study, conds, panel, meta)


def _contact_threshold(plan: AnalysisPlan) -> float:
    for mid in plan.metrics:
        p = plan.metric_params(mid)
        if "threshold_n" in p:
            return float(p["threshold_n"])
    return 0.5


def needle_force_profile(plan: AnalysisPlan, store: Any, study: Any, spec: FigureEntry) -> FigureData:
    """Axial force against depth along the planned path, one stored trial per condition."""

    def panel(cond: str, tid: int) -> pd.DataFrame | str:
        samples = store.read_samples(tid)
        need = ("x_mm", "y_mm", "z_mm", "fx_n", "fy_n", "fz_n")
        if samples.empty or any(c not in samples for c in need):
            return f"trial {tid} lacks samples of {', '.join(c for c in need if c not in samples)}"
        try:
            truth = _trial_truth(store, tid)
        except StudyctlError as exc:
            return str(exc)
        a = np.asarray(truth["incision_mm"], dtype=float)
        b = np.asarray(truth["tumour_center_mm"], dtype=float)
        u = (b - a) / np.linalg.norm(b - a)
        tip = samples[["x_mm", "y_mm", "z_mm"]].to_numpy(dtype=float)
        force = samples[["fx_n", "fy_n", "fz_n"]].to_numpy(dtype=float)
        if all(c in samples for c in ("dir_x", "dir_y", "dir_z")):
            axis = samples[["dir_x", "dir_y", "dir_z"]].to_numpy(dtype=float)
            norm = np.linalg.norm(axis, axis=1, keepdims=True)
            axis = np.divide(axis, norm, out=np.tile(u, (len(axis), 1)), where=norm > 0)
        else:
            axis = np.tile(u, (len(tip), 1))
        depth = (tip - a) @ u
        # The device pushes back against insertion: report the resisting force as positive.
        axial = -np.einsum("ij,ij->i", force, axis)
        keep = depth >= -2.0
        return pd.DataFrame({"x": depth[keep], "f_axial_n": axial[keep]})

    conds = list(spec.options.get("conditions") or plan.condition_ids[:2])
    meta = {"x_label": "depth along the planned path (mm)", "channels": [("f_axial_n", "axial force (N)", "left")]}
    return _per_condition(plan, store, study, conds, panel, meta)


def _trial_truth(store: Any, tid: int) -> Mapping[str, Any]:
    """The scene truth of a stored trial: its logged truth event, else rebuilt from the session plan."""
    from sqlalchemy import select

    from studyctl.analysis.metrics import rebuild_truth
    from studyctl.engine.plan import SessionPlan
    from studyctl.store.models import Event, Session, Trial

    with store.reading() as s:
        tr = s.get(Trial, tid)
        sess = s.get(Session, tr.session_id)
        ev = s.execute(
            select(Event.kind, Event.payload).where(Event.trial_id == tid, Event.kind.in_(("scene_truth", "truth")))
        ).first()
        plan_ev = s.execute(
            select(Event.payload)
            .where(Event.session_id == sess.id, Event.kind.in_(("session_plan", "plan_amended")))
            .order_by(Event.seq.desc())
        ).first()
    if ev is not None:
        return dict(ev[1] or {})
    plan = SessionPlan.from_json(plan_ev[0]["plan"])
    step = int((tr.outcome or {}).get("step", tr.plan_position))
    return rebuild_truth(plan, tr.placement or {}, int(sess.seed or 0), step)


def collect(
    plan: AnalysisPlan, *, db: str | None = None, workspace: str | Path | None = None, study: str | None = None
) -> dict[str, FigureData]:
    """Figure data for every signal figure of ``plan`` from the study database."""
    from studyctl.protocol import load_protocol_text
    from studyctl.store.workspace import open_study

    out: dict[str, FigureData] = {}
    with open_study(db, None if workspace is None else str(workspace), study) as opened:
        protocol = None
        if opened.study.protocol_text:
            protocol = load_protocol_text(opened.study.protocol_text, f"<protocol of {opened.study.name}>")
        for spec in plan.figures:
            try:
                if spec.kind == "controller_response":
                    if protocol is None:
                        out[spec.id] = FigureData(pd.DataFrame(), problem="the study stores no protocol")
                    else:
                        waves = spec.options.get("waves")
                        out[spec.id] = controller_response(
                            protocol,
                            conditions=spec.options.get("conditions"),
                            waves=[tuple(w) for w in waves] if waves else None,
                        )
                elif spec.kind == "force_trace":
                    out[spec.id] = force_trace(plan, opened.store, opened.study, spec)
                elif spec.kind == "needle_force_profile":
                    out[spec.id] = needle_force_profile(plan, opened.store, opened.study, spec)
            except StudyctlError as exc:
                out[spec.id] = FigureData(pd.DataFrame(), problem=str(exc))
    return out
