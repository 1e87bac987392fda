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

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd

from studyctl.analysis.catalog import SIGNAL_FIGURES
from studyctl.analysis.metrics import tumour_contact_mask
from studyctl.analysis.plan import AnalysisPlan, FigureEntry
from studyctl.analysis.results import FigureData
from studyctl.analysis.trials import StoredStudy, TrialView
from studyctl.errors import StudyctlError
from studyctl.store.reader import StudyReader

if TYPE_CHECKING:
    from studyctl.protocol import Protocol

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
    protocol: Protocol,
    *,
    conditions: Sequence[str] | None = None,
    waves: Sequence[tuple[float, float, float]] | None = None,
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


def _per_condition(
    plan: AnalysisPlan,
    study: StoredStudy,
    conds: Sequence[str],
    panel: Callable[[TrialView], pd.DataFrame | str],
    meta: dict[str, Any],
) -> FigureData:
    """One panel per condition, from its first completed trial.

    ``panel(trial)`` returns the panel's frame, or the text of why it cannot be drawn (the figure's
    ``problem`` lists those after the condition). Panels are labelled with the plan's condition labels;
    ``meta`` is added after ``panels``.
    """
    trials = study.first_completed(conds)
    labels = {c.id: c.display for c in plan.condition_levels}
    frames, panels, problems = [], [], []
    for cond in conds:
        if cond not in trials:
            problems.append(f"{cond}: no completed trial")
            continue
        frame = panel(trials[cond])
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


def force_trace(plan: AnalysisPlan, study: StoredStudy, spec: FigureEntry) -> FigureData:
    """Force and commands ±``window_s`` around the first tumour contact of one trial per condition.

    Tumour contact is what the contact metrics use (:func:`studyctl.analysis.metrics.tumour_contact_mask`):
    the probe over a tumour with the force above the threshold; those spans are shaded.
    """
    threshold = float(spec.options.get("threshold_n", _contact_threshold(plan)))
    window = float(spec.options.get("window_s", 3.0))

    def panel(trial: TrialView) -> pd.DataFrame | str:
        tid, samples = trial.trial_id, trial.samples
        try:
            contact = tumour_contact_mask(samples, trial.truth, threshold)
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
    return _per_condition(plan, study, conds, panel, meta)


def _contact_threshold(plan: AnalysisPlan) -> float:
    for mid in plan.metrics:
        p = plan.metric_params(mid)
        if "threshold_n" in p:
            return float(p["threshold_n"])
    return 0.5


def needle_force_profile(plan: AnalysisPlan, study: StoredStudy, spec: FigureEntry) -> FigureData:
    """Axial force against depth along the planned path, one stored trial per condition."""

    def panel(trial: TrialView) -> pd.DataFrame | str:
        tid, samples = trial.trial_id, trial.samples
        need = ("x_mm", "y_mm", "z_mm", "fx_n", "fy_n", "fz_n")
        if samples.empty or any(c not in samples for c in need):
            return f"trial {tid} lacks samples of {', '.join(c for c in need if c not in samples)}"
        try:
            truth = trial.truth
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
    return _per_condition(plan, study, conds, panel, meta)


def _controller_response(plan: AnalysisPlan, study: StoredStudy, spec: FigureEntry) -> FigureData:
    if study.protocol is None:
        return FigureData(pd.DataFrame(), problem="the study stores no protocol")
    waves = spec.options.get("waves")
    return controller_response(
        study.protocol, conditions=spec.options.get("conditions"), waves=[tuple(w) for w in waves] if waves else None
    )


#: The collector of each figure kind whose data do not come from the result tables
#: (:data:`studyctl.analysis.catalog.SIGNAL_FIGURES`; a test checks the two agree).
COLLECTORS: dict[str, Callable[[AnalysisPlan, StoredStudy, FigureEntry], FigureData]] = {
    "force_trace": force_trace,
    "needle_force_profile": needle_force_profile,
    "controller_response": _controller_response,
}


def needs_figure_data(plan: AnalysisPlan) -> bool:
    """Whether any figure of ``plan`` draws data from the study database (not from the result tables)."""
    return plan.data.source == "database" and any(f.kind in SIGNAL_FIGURES for f in plan.figures)


def collect(plan: AnalysisPlan, study: StoredStudy | StudyReader) -> dict[str, FigureData]:
    """Figure data for every signal figure of ``plan`` from a stored study (one reader per report)."""
    stored = study if isinstance(study, StoredStudy) else StoredStudy(study)
    out: dict[str, FigureData] = {}
    for spec in plan.figures:
        collector = COLLECTORS.get(spec.kind)
        if collector is None:
            continue
        try:
            out[spec.id] = collector(plan, stored, spec)
        except StudyctlError as exc:
            out[spec.id] = FigureData(pd.DataFrame(), problem=str(exc))
    return out
