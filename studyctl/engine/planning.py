"""Turn a protocol and a participant's stored schedule into the session plan the engine runs.

The schedule (``studyctl.protocol.Schedule``, drawn and stored at enrollment) fixes the condition order,
placements, time limits, familiarisation, breaks and questionnaires of every trial. This module only
lays them out as steps: instructions → [questionnaires at start] → for each trial: break before it,
familiarisation offered before it, the trial, the questionnaires after it → end.
"""

from __future__ import annotations

from typing import Any

from studyctl.engine.plan import (
    ConditionSpec,
    Instrument,
    Item,
    ReportSpec,
    ScalePoint,
    SessionPlan,
    Step,
)
from studyctl.errors import SessionError
from studyctl.protocol import Protocol, Schedule


def _instrument(protocol: Protocol, instrument_id: str) -> Instrument:
    src = protocol.instrument(instrument_id)
    items = []
    for item in src.items:
        scale = src.scale_of(item)
        points = tuple(ScalePoint(code, str(scale.anchors.get(code, ""))) for code in scale.codes)
        items.append(Item(item.id, item.text, points, item.reverse))
    return Instrument(src.id, str(src.version), src.title or src.id, tuple(items))


def _report(protocol: Protocol) -> ReportSpec:
    rep = protocol.trial.report
    if rep.kind == "grid_cell":
        if rep.grid is None:
            raise SessionError("protocol trial.report.kind is grid_cell but trial.report.grid is missing")
        return ReportSpec(
            "grid",
            columns=tuple(str(c) for c in range(1, rep.grid.columns + 1)),
            rows=tuple(str(r) for r in range(1, rep.grid.rows + 1)),
        )
    if rep.kind == "position":
        params = protocol.scene.params
        width = float(params.get("width_mm", params.get("size_mm", [120.0, 120.0])[0]
                                 if isinstance(params.get("size_mm"), list) else 120.0))
        height = float(params.get("height_mm", params.get("size_mm", [120.0, 120.0])[1]
                                  if isinstance(params.get("size_mm"), list) else 120.0))
        return ReportSpec("position", bounds_mm=(0.0, width, 0.0, height))
    return ReportSpec("none")


def _when(protocol: Protocol, instrument_id: str, last: bool) -> str:
    whens = [a.when for a in protocol.questionnaires if a.instrument == instrument_id]
    if "end" in whens and last:
        return "end"
    for w in whens:
        if w != "end" and w != "start":
            return w
    return whens[0] if whens else "after_condition"


def plan_for_participant(protocol: Protocol, schedule: Schedule) -> SessionPlan:
    """The session plan for one participant's stored schedule.

    Parameters
    ----------
    protocol
        The study's protocol (as stored with the study).
    schedule
        The participant's schedule, as stored at enrollment.

    Returns
    -------
    SessionPlan
        Self-contained and JSON-serialisable; stored with the session when it starts.
    """
    if schedule.protocol_sha256 and protocol.sha256 and schedule.protocol_sha256 != protocol.sha256:
        raise SessionError(
            f"the participant's schedule was drawn from protocol {schedule.protocol_sha256[:12]}…, but the study "
            f"holds protocol {protocol.sha256[:12]}…; the schedule no longer matches the protocol"
        )
    conditions = {
        c.id: ConditionSpec(
            id=c.id,
            label=c.label or c.id,
            controller=None if c.manual else c.controller,
            params=dict(c.params),
            visual=c.visual,
            manual=bool(c.manual),
            view_label=c.view_label,
        )
        for c in protocol.conditions
    }
    instrument_ids: list[str] = []
    steps: list[Step] = []
    pos = 0

    def add(kind: str, **kw: Any) -> None:
        nonlocal pos
        pos += 1
        steps.append(Step(pos, kind, **kw))

    intro = protocol.trial.instructions or protocol.study.description or protocol.study.title
    add("instructions", data={"text": intro})
    for inst in schedule.questionnaires_start:
        instrument_ids.append(inst)
        add("questionnaire", data={"instrument": inst, "when": "start"})
    fam = protocol.trial.familiarisation
    n = len(schedule.entries)
    for i, e in enumerate(schedule.entries):
        if e.break_before_s > 0:
            add("break", condition=e.condition, block=e.block, duration_s=float(e.break_before_s))
        if e.familiarisation_max_s:
            add(
                "familiarisation",
                condition=e.condition,
                block=e.block,
                duration_s=float(e.familiarisation_max_s),
                data={
                    "can_end_early": bool(fam.can_end_early) if fam else True,
                    "instructions": fam.instructions if fam else "",
                },
            )
        add(
            "trial",
            condition=e.condition,
            block=e.block,
            repetition=e.repetition,
            trial_index=e.trial,
            duration_s=e.time_limit_s,
            data={"placement": e.scene_placement(), "schedule_position": e.position},
        )
        for inst in e.questionnaires_after:
            instrument_ids.append(inst)
            when = _when(protocol, inst, last=i == n - 1)
            add(
                "questionnaire",
                condition=None if when == "end" else e.condition,
                block=None if when == "end" else e.block,
                data={"instrument": inst, "when": when},
            )
    add("end", data={"text": "The session is complete. Thank you for taking part!"})
    devices = protocol.devices
    virtual = protocol.participants.virtual
    return SessionPlan(
        steps=tuple(steps),
        conditions=conditions,
        instruments={i: _instrument(protocol, i) for i in dict.fromkeys(instrument_ids)},
        report=_report(protocol),
        scene=protocol.scene.plugin,
        scene_spec=dict(protocol.scene.params),
        hardware_device=None if devices.hardware is None else devices.hardware.model_dump(),
        simulated_device=devices.simulated.model_dump(),
        virtual_participant=None if virtual is None else virtual.model_dump(),
        requests=tuple(protocol.trial.requests),
        interrupted_trial=protocol.resume.interrupted_trial,
        checkpoint=protocol.resume.checkpoint,
        study=protocol.study.id,
    )
