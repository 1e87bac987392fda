"""``studyctl export DIR [--format csv|parquet]``: a study's tidy tables, a data dictionary and a Frictionless
data package (``datapackage.json``: every file, its columns with type, unit and description).

Tables (one row per observation, stable keys, 1-based human ordinals, missing = empty cell / null):

* ``trials`` – one row per trial attempt (repeats and replacements included, with their status);
* ``events`` – every session event in order; the payload's fields are columns ``payload_<field>`` (lists and
  nested objects as JSON text);
* ``responses`` – one row per questionnaire answer (the code, its anchor label, the instrument version);
* ``reports`` – one row per location report (grid cell or position in mm);
* ``records`` – the coordinator's consent, withdrawal and note records (from the audit log);
* ``samples_<condition>`` – the high-rate samples of every trial of one condition stacked into one long table
  (the trials of a condition share their channels; skipped with ``samples=False``);
* ``data_dictionary.json`` and ``datapackage.json`` – description, unit and type of every column of every file.

Parquet files are zstd-compressed with typed columns; :func:`read_export` loads either format the same way.
"""

from __future__ import annotations

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
from studyctl.store.coordination import RECORD_COLUMNS, coordination_records
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
EVENT_BASE_COLUMNS = {
    **_SESSION_KEYS,
    "seq": ("1-based order of the event in its session", "", "integer"),
    "trial_id": ("Trial attempt the event happened in (empty: between trials)", "", "integer"),
    "t": ("Time: trial time since the loop started for events with a trial_id, else session time", "s", "number"),
    "t_wall": ("Wall-clock time of the commit (UTC, ISO 8601)", "", "datetime"),
    "kind": ("Event kind (step_enter, step_done, trial_start, scan, report, safety kinds, answer …)", "", "string"),
}  # then one payload_<field> column per payload field (see _payload_columns)
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


def _private_binary(path: Path):
    fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
    return os.fdopen(fd, "wb")


FORMATS = ("csv", "parquet")
PANDAS_TYPES = {"integer": "Int64", "number": "float64", "boolean": "boolean"}
# Frictionless field types of the dictionary's types (JSON text stays a string: one value per cell)
FRICTIONLESS_TYPES = {"integer": "integer", "number": "number", "boolean": "boolean", "datetime": "datetime",
                      "string": "string", "json": "string"}


def _typed(columns: dict[str, tuple[str, str, str]], rows: list[list[Any]]) -> pd.DataFrame:
    """Rows as a frame whose columns carry the dictionary's types (nullable integers and booleans)."""
    frame = pd.DataFrame(rows, columns=list(columns), dtype=object)
    for name, (_, _, kind) in columns.items():
        frame[name] = _cast(frame[name], kind)
    return frame


def _cast(col: pd.Series, kind: str) -> pd.Series:
    if kind in PANDAS_TYPES:
        return col.astype(PANDAS_TYPES[kind])
    # text: "" and a missing value are the same empty cell in CSV, so both are null
    return col.astype("string").replace("", pd.NA)


def _payload_columns(events: list[tuple[list[Any], Any]]) -> tuple[dict[str, tuple[str, str, str]], list[list[Any]]]:
    """Event payloads spread into ``payload_<field>`` columns with one type each (mixed types → JSON text)."""
    fields: dict[str, list[Any]] = {}
    kinds: dict[str, set[str]] = {}
    for i, (base, payload) in enumerate(events):
        items = payload.items() if isinstance(payload, dict) else ([("value", payload)] if payload is not None else [])
        for key, value in items:
            name = f"payload_{key}"
            fields.setdefault(name, [None] * len(events))[i] = value
            kinds.setdefault(name, set()).add(str(base[-1]))
    columns: dict[str, tuple[str, str, str]] = {}
    for name, values in fields.items():
        present = [v for v in values if v is not None]
        if present and all(isinstance(v, bool) for v in present):
            kind = "boolean"
        elif present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
            kind = "integer"
        elif present and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in present):
            kind = "number"
        else:
            kind = "string"
            fields[name] = [v if v is None or isinstance(v, str) else _json(v) for v in values]
        seen = ", ".join(sorted(kinds[name])[:8]) + (" …" if len(kinds[name]) > 8 else "")
        columns[name] = (f"Payload field {name[8:]!r} of events of kind {seen} (lists and objects as JSON)",
                         channel_unit(name), kind)
    rows = [[*base, *(fields[n][i] for n in columns)] for i, (base, _) in enumerate(events)]
    return columns, rows


# Encodings tried per column on its first rows (the smallest wins): sampled signals differ — a smooth position
# packs best as plain values, a noisy force as byte-stream-split floats (exponent and sign bytes compress, the
# mantissa does not), a quantised or repeated value (keys, ADC counts, flags) as a dictionary. Measured on
# 2-person simulated studies of the four protocols this takes the sample tables from 0.19-0.26 of the CSV to
# 0.08-0.21 (seed 002's forces are full-precision doubles: ~7 bytes a value is their floor).
_PROBE_ROWS = 50_000
_PARQUET_LEVEL = 15  # zstd: 2 % smaller than 12 at 1.8 × its CPU; 19 gains 0.4 % more at 3 × (one 117k-row table)


def _parquet_encodings(table) -> tuple[list[str], list[str]]:  # noqa: ANN001 - pyarrow.Table
    """(columns to dictionary-encode, float columns to byte-stream-split): the smaller of the candidates per
    column, by writing its first :data:`_PROBE_ROWS` rows alone at a fast zstd level."""
    import io

    import pyarrow as pa
    import pyarrow.parquet as pq

    def size(column, **options) -> int:  # noqa: ANN001
        buf = io.BytesIO()
        pq.write_table(column, buf, compression="zstd", compression_level=3, write_statistics=False, **options)
        return buf.getbuffer().nbytes

    probe = table.slice(0, _PROBE_ROWS).replace_schema_metadata(None)
    dictionary, split = [], []
    for name in table.column_names:
        one = probe.select([name])
        sizes = {"plain": size(one, use_dictionary=False), "dictionary": size(one, use_dictionary=True)}
        if pa.types.is_floating(table.schema.field(name).type):
            sizes["split"] = size(one, use_dictionary=False, use_byte_stream_split=True)
        best = min(sizes, key=sizes.get)
        (dictionary if best == "dictionary" else split if best == "split" else []).append(name)
    return dictionary, split


def _write_table(out: Path, name: str, frame: pd.DataFrame, fmt: str) -> str:
    file = f"{name}.{fmt}"
    if fmt == "parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.Table.from_pandas(frame, preserve_index=False)  # keeps pandas' dtypes in the schema metadata
        dictionary, split = _parquet_encodings(table)
        # min/max statistics for numbers, flags and the participant key (row-group skipping by readers); not
        # for text, whose min/max of long JSON payloads cost more than the column (15 of 43 KB of events)
        stats = [f.name for f in table.schema if f.name == "participant" or not
                 (pa.types.is_string(f.type) or pa.types.is_large_string(f.type))]
        with _private_binary(out / file) as fh:
            pq.write_table(table, fh, compression="zstd", compression_level=_PARQUET_LEVEL,
                           use_dictionary=dictionary or False, use_byte_stream_split=split or False,
                           write_statistics=stats or False)
    else:
        with _private(out / file) as fh:
            frame.to_csv(fh, index=False)
    return file


def _datapackage(target: Any, files: dict[str, dict[str, tuple[str, str, str]]], fmt: str) -> dict[str, Any]:
    """A Frictionless (tabular) data package describing every exported file from the data dictionary."""
    resources = []
    for file, columns in files.items():
        fields = []
        for col, (description, unit, kind) in columns.items():
            field: dict[str, Any] = {"name": col, "type": FRICTIONLESS_TYPES[kind], "description": description}
            if unit:
                field["unit"] = unit
            if kind == "json":
                field["format"] = "json"
            fields.append(field)
        resource: dict[str, Any] = {
            "name": file.rsplit(".", 1)[0].lower().replace(" ", "_"),
            "path": file,
            "format": fmt,
            "mediatype": "text/csv" if fmt == "csv" else "application/vnd.apache.parquet",
            "schema": {"fields": fields, "missingValues": [""]},
        }
        if fmt == "csv":
            resource["encoding"] = "utf-8"
            resource["profile"] = "tabular-data-resource"
        resources.append(resource)
    return {
        "profile": "tabular-data-package" if fmt == "csv" else "data-package",
        "name": str(target.name).lower().replace("_", "-"),
        "title": str(target.name),
        "description": f"Export of study {target.name} by studyctl {__version__} (protocol sha256 "
                       f"{target.protocol_sha256}); units per field in 'unit'.",
        "resources": resources,
    }


def read_export(directory: str | Path) -> dict[str, pd.DataFrame]:
    """Every table of an export (CSV or Parquet), typed from its ``datapackage.json``: name → frame.

    Both formats of the same study read back equal (text cells: empty = missing)."""
    folder = Path(directory)
    try:
        package = json.loads((folder / "datapackage.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UsageError(f"{folder}: no readable datapackage.json ({exc}); is this a studyctl export?") from None
    inverse = {"integer": "integer", "number": "number", "boolean": "boolean"}
    out: dict[str, pd.DataFrame] = {}
    for res in package["resources"]:
        path = folder / res["path"]
        kinds = {f["name"]: inverse.get(f["type"], "string") for f in res["schema"]["fields"]}
        if res["format"] == "parquet":
            frame = pd.read_parquet(path, engine="pyarrow")
        else:
            frame = pd.read_csv(path, dtype=object, keep_default_na=False, na_values=[""])
            for name, kind in kinds.items():
                if kind == "boolean":
                    frame[name] = frame[name].map({"True": True, "False": False, "true": True, "false": False})
                elif kind in ("integer", "number"):
                    frame[name] = pd.to_numeric(frame[name])
        for name, kind in kinds.items():
            frame[name] = _cast(frame[name], kind)
        out[res["name"]] = frame.reset_index(drop=True)
    return out


def export_study(store: StudyStore, directory: str | Path, *, study: str | None = None, samples: bool = True,
                 process_info: bool = False, format: str = "csv") -> ExportResult:
    """Write a study's trials, events, responses, reports (and samples) as tidy tables (CSV or Parquet) plus a
    data dictionary and a Frictionless ``datapackage.json``.

    Files are created 0600 (a new folder 0700), like the database. Host names and process ids (where a
    session ran) are left out of the events unless ``process_info``.

    Raises :class:`UsageError` when ``directory`` exists and is not an empty folder (nothing is overwritten)
    or ``format`` is not csv or parquet.
    """
    fmt = str(format).lower()
    if fmt not in FORMATS:
        raise UsageError(f"export format {format!r} is unknown; allowed: {', '.join(FORMATS)}")
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
        records = coordination_records(s, target)
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
    event_cols, event_rows = _payload_columns([
        ([code[e.session_id], e.session_id, e.seq, e.trial_id, e.t_mono, _iso(e.t_wall), e.kind],
         e.payload if process_info else _without_process(e.payload))
        for e in events if process_info or e.kind not in PROCESS_EVENTS
    ])
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
    tables: dict[str, tuple[dict[str, tuple[str, str, str]], pd.DataFrame]] = {
        "trials": (TRIAL_COLUMNS, _typed(TRIAL_COLUMNS, trial_rows)),
        "events": ({**EVENT_BASE_COLUMNS, **event_cols}, _typed({**EVENT_BASE_COLUMNS, **event_cols}, event_rows)),
        "responses": (RESPONSE_COLUMNS, _typed(RESPONSE_COLUMNS, resp_rows)),
        "reports": (REPORT_COLUMNS, _typed(REPORT_COLUMNS, report_rows)),
        "records": (RECORD_COLUMNS, _typed(RECORD_COLUMNS, records)),
    }
    if samples:
        tables.update(_sample_tables(store, trials, people))
    rows: dict[str, int] = {}
    described: dict[str, dict[str, tuple[str, str, str]]] = {}
    for name, (columns, frame) in tables.items():
        file = _write_table(out, name, frame, fmt)
        rows[file] = len(frame)
        described[file] = columns
    dictionary: dict[str, Any] = {
        "studyctl_version": __version__,
        "study": target.name,
        "protocol_sha256": target.protocol_sha256,
        "format": fmt,
        "files": {name: _describe(columns) for name, columns in described.items()},
    }
    with _private(out / "data_dictionary.json") as fh:
        fh.write(json.dumps(dictionary, indent=2, ensure_ascii=False) + "\n")
    with _private(out / "datapackage.json") as fh:
        fh.write(json.dumps(_datapackage(target, described, fmt), indent=2, ensure_ascii=False) + "\n")
    return ExportResult(out, rows)


def _sample_tables(store: StudyStore, trials: list, people: dict) -> dict[str, tuple[dict, pd.DataFrame]]:
    """One long table per condition: its trials' samples stacked (participant, trial_id, t, channels)."""
    groups: dict[str, list[pd.DataFrame]] = {}
    channels: dict[str, list[str]] = {}
    for t in trials:
        if t.status == "planned":
            continue
        df = store.read_samples(t.id)
        if df.empty:
            continue
        group = _safe_name(t.condition or "none")
        names = channels.setdefault(group, [])
        names += [c for c in df.columns if c != "t" and c not in names]
        df.insert(0, "trial_id", t.id)
        df.insert(0, "participant", people[t.participant_id].code)
        groups.setdefault(group, []).append(df)
    out = {}
    for group, frames in groups.items():
        cols = {
            "participant": TRIAL_COLUMNS["participant"],
            "trial_id": TRIAL_COLUMNS["trial_id"],
            "t": ("Trial time since the loop started", "s", "number"),
        }
        for c in channels[group]:
            cols[c] = (f"Channel {c} (sensor reading, or command written to the device after the safety layer)",
                       channel_unit(c), "number")
        frame = pd.concat(frames, ignore_index=True).reindex(columns=list(cols))
        frame["participant"] = frame["participant"].astype("string")
        frame["trial_id"] = frame["trial_id"].astype("Int64")
        for c in list(cols)[2:]:
            frame[c] = frame[c].astype("float64")
        out[f"samples_{group}"] = (cols, frame)
    return out


def _safe_name(text: str) -> str:
    return "".join(ch if ch.isalnum() or ch in "-_" else "_" for ch in text)


def _describe(columns: dict[str, tuple[str, str, str]]) -> dict[str, dict[str, str]]:
    return {name: {"description": d, "unit": u, "type": ty} for name, (d, u, ty) in columns.items()}

