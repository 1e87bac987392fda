"""``studyctl export DIR``: tidy CSV files of a study plus a JSON data dictionary of every column.

Files (one row per observation, stable keys, 1-based human ordinals, missing = empty cell):

* ``trials.csv`` – one row per trial attempt (repeats and replacements included, with their status);
* ``events.csv`` – every session event in order (payload as JSON text);
* ``responses.csv`` – one row per questionnaire answer (the code, its anchor label, the instrument version);
* ``reports.csv`` – one row per location report (grid cell or position in mm);
* ``samples.csv`` – the high-rate samples of every trial, one row per sample (skipped with ``samples=False``);
* ``data_dictionary.json`` – description, unit and type of every column of every file.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd
from sqlalchemy import select

from studyctl import __version__
from studyctl.engine.plan import SessionPlan
from studyctl.errors import SessionError, UsageError
from studyctl.store import StudyStore
from studyctl.store.models import Event, LocationReport, Participant, QuestionnaireResponse, Session, Trial

UNIT_SUFFIXES = {
    "_n": "N", "_mm": "mm", "_m": "m", "_kpa": "kPa", "_psi": "psi", "_pct": "%", "_s": "s", "_ms": "ms",
    "_deg": "degree", "_rad": "rad", "_hz": "Hz", "_v": "V", "_mm_s": "mm/s", "_n_mm": "N/mm", "_adc": "ADC counts",
}

TRIAL_COLUMNS = {
    "study": ("Study name", "", "string"),
    "participant": ("Pseudonymous participant code", "", "string"),
    "stratum": ("Between-subject group (stratum) of the participant", "", "string"),
    "session_id": ("Session id", "", "integer"),
    "trial_id": ("Trial attempt id (unique in the database)", "", "integer"),
    "plan_position": ("1-based planned trial number in the participant's schedule", "", "integer"),
    "step": ("1-based position of the trial step in the session plan", "", "integer"),
    "attempt": ("1-based attempt at this plan step (a repeated trial has several)", "", "integer"),
    "condition": ("Condition id", "", "string"),
    "block": ("1-based block", "", "integer"),
    "repetition": ("1-based repetition of the condition within its block", "", "integer"),
    "status": ("planned, running, completed, aborted or invalid", "", "string"),
    "timed_out": ("True when the hard time limit ended the trial", "", "boolean"),
    "ended_by": ("finish, time_limit, abort, pause or fault", "", "string"),
    "duration_s": ("Trial duration from loop start to its end", "s", "number"),
    "time_limit_s": ("Hard time limit (empty: none)", "s", "number"),
    "scans": ("CT scans requested (counted only in on-request visual conditions)", "count", "integer"),
    "reports": ("Location reports accepted", "count", "integer"),
    "ticks": ("Controller loop iterations", "count", "integer"),
    "rate_hz": ("Controller loop rate", "Hz", "number"),
    "replaces_trial_id": ("Trial attempt this one repeats or replaces", "", "integer"),
    "reason": ("Why the trial was aborted or marked invalid", "", "string"),
    "placement": ("Scene placement of hidden targets (JSON): sites by item, orientation", "", "json"),
    "started_at": ("Wall-clock start (UTC, ISO 8601)", "", "datetime"),
    "ended_at": ("Wall-clock end (UTC, ISO 8601)", "", "datetime"),
}
# the key columns every per-session file starts with, described once
_SESSION_KEYS = {name: TRIAL_COLUMNS[name] for name in ("participant", "session_id")}
EVENT_COLUMNS = {
    **_SESSION_KEYS,
    "seq": ("1-based order of the event in its session", "", "integer"),
    "trial_id": ("Trial attempt the event happened in (empty: between trials)", "", "integer"),
    "t": ("Time: trial time since the loop started for events with a trial_id, else session time", "s", "number"),
    "t_wall": ("Wall-clock time of the commit (UTC, ISO 8601)", "", "datetime"),
    "kind": ("Event kind (step_enter, step_done, trial_start, scan, report, safety kinds, answer …)", "", "string"),
    "payload": ("Event details (JSON)", "", "json"),
}
RESPONSE_COLUMNS = {
    **_SESSION_KEYS,
    "step": ("Plan step position of the questionnaire", "", "integer"),
    "condition": ("Condition the questionnaire followed (empty: start or end of study)", "", "string"),
    "instrument": ("Instrument id", "", "string"),
    "instrument_version": ("Instrument version the answer was given on", "", "string"),
    "item": ("Item id", "", "string"),
    "code": ("Answer code on the item's scale (stored value; never the label)", "code", "integer"),
    "label": ("Anchor label of the code (empty when the point has none)", "", "string"),
    "reverse": ("True when the item is reverse-keyed", "", "boolean"),
    "answered_at": ("Wall-clock time of the answer (UTC, ISO 8601)", "", "datetime"),
}
REPORT_COLUMNS = {
    **_SESSION_KEYS,
    "trial_id": TRIAL_COLUMNS["trial_id"],
    "t": ("Trial time of the report", "s", "number"),
    "column": ("Reported grid column (grid-cell reports)", "", "string"),
    "row": ("Reported grid row (grid-cell reports)", "", "string"),
    "x_mm": ("Reported x position (position reports)", "mm", "number"),
    "y_mm": ("Reported y position (position reports)", "mm", "number"),
    "correct": ("Scored correct (empty until scored by the analysis)", "", "boolean"),
}


def channel_unit(name: str) -> str:
    """Unit of a channel from its name suffix (``force_n`` → N); empty when the suffix is unknown."""
    for suffix in sorted(UNIT_SUFFIXES, key=len, reverse=True):
        if name.lower().endswith(suffix):
            return UNIT_SUFFIXES[suffix]
    return ""


@dataclass(frozen=True)
class ExportResult:
    """What :func:`export_study` wrote: file name → row count."""

    directory: Path
    rows: dict[str, int]

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame(sorted(self.rows.items()), columns=["file", "rows"])


def _iso(value: Any) -> str:
    return "" if value is None else value.isoformat()


def _json(value: Any) -> str:
    return "" if value is None else json.dumps(value, sort_keys=True, ensure_ascii=False)


def _private(path: Path):
    """A new text file readable by its owner only (0600), like the study database: exports hold study data."""
    fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
    return os.fdopen(fd, "w", newline="", encoding="utf-8")


# Where a session ran (host name, process id) is operational, not study data: left out unless asked for.
PROCESS_EVENTS = frozenset({"session_process"})
PROCESS_KEYS = frozenset({"host", "pid", "hostname"})


def _without_process(payload: Any) -> Any:
    if isinstance(payload, dict):
        return {k: v for k, v in payload.items() if k not in PROCESS_KEYS}
    return payload


def _write(path: Path, columns: list[str], rows: list[list[Any]]) -> int:
    with _private(path) as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for r in rows:
            w.writerow(["" if v is None else v for v in r])
    return len(rows)


def export_study(store: StudyStore, directory: str | Path, *, study: str | None = None, samples: bool = True,
                 process_info: bool = False) -> ExportResult:
    """Write a study's trials, events, responses, reports (and samples) as tidy CSV plus a data dictionary.

    Files are created 0600 (a new folder 0700), like the database. Host names and process ids (where a
    session ran) are left out of ``events.csv`` unless ``process_info``.

    Raises :class:`UsageError` when ``directory`` exists and is not an empty folder (nothing is overwritten).
    """
    out = Path(directory)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise UsageError(f"{out} exists and is not an empty folder; export into a new or empty folder")
    try:
        out.mkdir(parents=True, exist_ok=True, mode=0o700)
    except OSError as exc:
        raise UsageError(f"cannot create {out}: {exc.strerror}; choose a writable folder") from None
    target = store.get_study(study)
    with store.reading() as s:
        people = {p.id: p for p in s.scalars(select(Participant).where(Participant.study_id == target.id))}
        sessions = {x.id: x for x in s.scalars(select(Session).where(Session.participant_id.in_(list(people))))}
        trials = list(s.scalars(select(Trial).where(Trial.session_id.in_(list(sessions))).order_by(Trial.id)))
        events = s.execute(select(Event).where(Event.session_id.in_(list(sessions)))
                           .order_by(Event.session_id, Event.seq)).scalars().all()
        responses = list(s.scalars(select(QuestionnaireResponse)
                                   .where(QuestionnaireResponse.participant_id.in_(list(people)))
                                   .order_by(QuestionnaireResponse.id)))
        reports = list(s.scalars(select(LocationReport).where(LocationReport.trial_id.in_([t.id for t in trials]))
                                 .order_by(LocationReport.id)))
    plans: dict[int, SessionPlan] = {}
    for ev in events:
        if ev.kind in ("session_plan", "plan_amended") and ev.payload and "plan" in ev.payload:
            plans[ev.session_id] = SessionPlan.from_json(ev.payload["plan"])
    code = {sid: people[x.participant_id].code for sid, x in sessions.items()}
    trial_session = {t.id: t.session_id for t in trials}

    trial_rows = []
    for t in trials:
        o = dict(t.outcome or {})
        p = people[t.participant_id]
        trial_rows.append([
            target.name, p.code, p.stratum, t.session_id, t.id, t.plan_position, o.get("step"), o.get("attempt"),
            t.condition, t.block, t.repetition, t.status, t.timed_out, o.get("ended_by"), o.get("duration_s"),
            t.time_limit_s, o.get("scans"), o.get("reports"), o.get("ticks"), o.get("rate_hz"), t.replaces_trial_id,
            t.invalid_reason, _json(t.placement), _iso(t.started_at), _iso(t.ended_at),
        ])
    event_rows = [
        [code[e.session_id], e.session_id, e.seq, e.trial_id, e.t_mono, _iso(e.t_wall), e.kind,
         _json(e.payload if process_info else _without_process(e.payload))]
        for e in events if process_info or e.kind not in PROCESS_EVENTS
    ]
    resp_rows = []
    for r in responses:
        step = int(r.context.split(":", 1)[1]) if r.context and r.context.startswith("step:") else None
        plan = plans.get(r.session_id)
        label, reverse, cond = "", None, None
        if plan is not None and r.instrument in plan.instruments:
            item = next((i for i in plan.instruments[r.instrument].items if i.id == r.item), None)
            if item is not None:
                label = next((pt.label for pt in item.scale if pt.code == r.code), "")
                reverse = item.reverse
            if step is not None:
                try:
                    cond = plan.step(step).condition
                except SessionError:  # the answer names a step the plan does not have
                    cond = None
        resp_rows.append([people[r.participant_id].code, r.session_id, step, cond, r.instrument, r.instrument_version,
                          r.item, r.code, label, reverse, _iso(r.answered_at)])
    report_rows = [
        [code[trial_session[r.trial_id]], trial_session[r.trial_id], r.trial_id, r.t, r.payload.get("column"),
         r.payload.get("row"), r.payload.get("x_mm"), r.payload.get("y_mm"), r.correct]
        for r in reports
    ]
    tables = {
        "trials.csv": (TRIAL_COLUMNS, trial_rows),
        "events.csv": (EVENT_COLUMNS, event_rows),
        "responses.csv": (RESPONSE_COLUMNS, resp_rows),
        "reports.csv": (REPORT_COLUMNS, report_rows),
    }
    rows = {name: _write(out / name, list(columns), body) for name, (columns, body) in tables.items()}
    dictionary: dict[str, Any] = {
        "studyctl_version": __version__,
        "study": target.name,
        "protocol_sha256": target.protocol_sha256,
        "files": {name: _describe(columns) for name, (columns, _) in tables.items()},
    }
    if samples:
        channels: list[str] = []
        frames = []
        for t in trials:
            if t.status == "planned":
                continue
            df = store.read_samples(t.id)
            if df.empty:
                continue
            for c in df.columns:
                if c != "t" and c not in channels:
                    channels.append(c)
            df.insert(0, "trial_id", t.id)
            df.insert(0, "participant", people[t.participant_id].code)
            frames.append(df)
        cols = ["participant", "trial_id", "t", *channels]
        if frames:
            with _private(out / "samples.csv") as fh:
                pd.concat(frames, ignore_index=True).reindex(columns=cols).to_csv(fh, index=False)
            rows["samples.csv"] = int(sum(len(f) for f in frames))
        else:
            _write(out / "samples.csv", cols, [])
            rows["samples.csv"] = 0
        sample_cols = {
            "participant": TRIAL_COLUMNS["participant"],
            "trial_id": TRIAL_COLUMNS["trial_id"],
            "t": ("Trial time since the loop started", "s", "number"),
        }
        for c in channels:
            unit = channel_unit(c)
            sample_cols[c] = (f"Channel {c} (sensor reading, or command written to the device after the safety "
                              "layer)", unit, "number")
        dictionary["files"]["samples.csv"] = _describe(sample_cols)
    with _private(out / "data_dictionary.json") as fh:
        fh.write(json.dumps(dictionary, indent=2, ensure_ascii=False) + "\n")
    return ExportResult(out, rows)


def _describe(columns: dict[str, tuple[str, str, str]]) -> dict[str, dict[str, str]]:
    return {name: {"description": d, "unit": u, "type": ty} for name, (d, u, ty) in columns.items()}

