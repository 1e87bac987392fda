"""Every stored record of a session is covered by the audit hash chain.

Trials (with their outcome), events, questionnaire answers, location reports and sample chunks are not
chained row by row; instead the session's writer *seals* them: in the same transaction that writes them,
a ``records.seal`` audit row lists the digest of every record of the session that is new or changed
since the previous seal (``{"trial": {id: [fields, outcome]}, "event": {id: digest}, …}``). The audit
row is hash-chained like every other, so a record can only be changed, removed or added unseen by
rewriting the chain from that seal on, which the head anchored outside the database
(:mod:`studyctl.store.anchor`) reveals.

:func:`verify_records` recomputes each record's digest from what is stored and names every record that
was edited (its digest differs from the sealed one), deleted (sealed but missing) or inserted (never
sealed). Records written after the last seal of a session that is still unfinished (the trial that was
running when a process died) are reported as pending, not as tampering: the next resume seals them.
Sample chunks carry their digest in a column, computed from the raw blobs when the chunk is written,
so sealing never re-reads the blobs; ``db check`` recomputes it.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import Any

from sqlalchemy import bindparam, select
from sqlalchemy.orm import Session as OrmSession

from studyctl.store.audit import append_audit, canonical_json
from studyctl.store.models import (
    AuditLog,
    Event,
    LocationReport,
    QuestionnaireResponse,
    SampleChunk,
    Session,
    Trial,
)

SEAL_ACTION = "records.seal"
COVERAGE_ACTION = "records.coverage_start"
ERASE_ACTION = "participant.erase"  # studyctl.store.erasure: records removed at a participant's request
UNFINISHED = ("running", "paused", "interrupted")
# name in seals and messages → model; trials are sealed as [fields digest, outcome digest]
KINDS = ("trial", "event", "answer", "report", "chunk")
_LABEL = {"trial": "trial", "event": "event", "answer": "answer", "report": "location report",
          "chunk": "sample chunk"}
_TRIAL_FIELDS = ("id", "session_id", "participant_id", "plan_position", "condition", "block", "repetition",
                 "placement", "time_limit_s", "status", "timed_out", "started_at", "ended_at", "replaces_trial_id",
                 "invalid_reason")
_EVENT_FIELDS = ("id", "session_id", "trial_id", "seq", "t_mono", "t_wall", "kind", "payload")
_ANSWER_FIELDS = ("id", "participant_id", "session_id", "trial_id", "instrument", "instrument_version", "item",
                  "code", "answered_at", "context")
_REPORT_FIELDS = ("id", "trial_id", "t", "payload", "correct")
_CHUNK_FIELDS = ("trial_id", "stream", "chunk_index", "t0", "t1", "n", "channels", "dtype")


def _norm(value: Any) -> Any:
    if isinstance(value, datetime):
        return value.astimezone(UTC).isoformat(timespec="microseconds")
    if isinstance(value, float):
        return repr(value)  # exact; also keeps 1.0 and 1 apart the same way on every backend
    if isinstance(value, dict):
        return {str(k): _norm(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_norm(v) for v in value]
    return value


def _digest(values: dict[str, Any]) -> str:
    return hashlib.sha256(canonical_json(_norm(values)).encode("utf-8")).hexdigest()


def _fields(row: Any, names: tuple[str, ...]) -> dict[str, Any]:
    # by column name: a core Row's attribute ``t`` is its tuple, not the column t
    mapping = getattr(row, "_mapping", None)
    if mapping is not None:
        return {k: mapping[k] for k in names}
    return {k: getattr(row, k) for k in names}


def trial_digest(row: Trial) -> list[str]:
    """``[digest of the trial's fields, digest of its outcome]`` (kept apart to name an edited outcome)."""
    return [_digest(_fields(row, _TRIAL_FIELDS)), _digest({"outcome": row.outcome})]


def event_digest(row: Event) -> str:
    return _digest(_fields(row, _EVENT_FIELDS))


def answer_digest(row: QuestionnaireResponse) -> str:
    return _digest(_fields(row, _ANSWER_FIELDS))


def report_digest(row: LocationReport) -> str:
    return _digest(_fields(row, _REPORT_FIELDS))


def chunk_digest(header: dict[str, Any], t: bytes, data: bytes) -> str:
    """sha256 of a sample chunk's key fields (trial, stream, index, t0, t1, n, channels, dtype) and blobs."""
    h = hashlib.sha256(canonical_json(_norm({k: header[k] for k in _CHUNK_FIELDS})).encode("utf-8"))
    h.update(b"\0")
    h.update(bytes(t))
    h.update(b"\0")
    h.update(bytes(data))
    return h.hexdigest()


def stored_chunk_digest(row: Any) -> str:
    blobs = _fields(row, ("t", "data"))
    return chunk_digest(_fields(row, _CHUNK_FIELDS), blobs["t"], blobs["data"])


# ------------------------------------------------------------------------------------------- sealing


@dataclass
class SealMark:
    """What of one session is sealed already: the highest sealed id per append-only kind, trial digests."""

    last: dict[str, int] = field(default_factory=lambda: {k: 0 for k in KINDS if k != "trial"})
    trials: dict[int, list[str]] = field(default_factory=dict)

    def fold(self, details: dict[str, Any]) -> None:
        for kind in KINDS:
            for key, digest in (details.get(kind) or {}).items():
                if kind == "trial":
                    self.trials[int(key)] = list(digest)
                else:
                    self.last[kind] = max(self.last[kind], int(key))


def load_mark(tx: OrmSession, session_id: int) -> SealMark:
    """The seal state of a session, rebuilt from its ``records.seal`` audit rows (for a resume)."""
    mark = SealMark()
    seals = (AuditLog.action == SEAL_ACTION) & (AuditLog.entity == "session") & \
        (AuditLog.entity_id == str(session_id))
    for action, details in tx.execute(select(AuditLog.action, AuditLog.details)
                                      .where(seals | (AuditLog.action == ERASE_ACTION)).order_by(AuditLog.id)):
        body = json.loads(details)
        if action == ERASE_ACTION:
            # SQLite hands an erased session's id to the next new session: its seals start again
            if session_id in (body.get("sessions") or ()):
                mark = SealMark()
            continue
        mark.fold(body)
    return mark


# Sealing runs in every write transaction of a session (hundreds per session), so its five SELECTs are built once,
# with the session id and the last sealed ids as parameters, and run on the transaction's connection (Core): no ORM
# statement handling per query, the same SQL, rows and transaction (seal_session flushes first).
_SID, _LAST = bindparam("session_id"), bindparam("last")
_TRIAL_IDS = select(Trial.id).where(Trial.session_id == _SID).scalar_subquery()
_TRIALS = select(Trial.__table__).where(Trial.session_id == _SID)
_NEW_ROWS = {
    "event": (select(Event.__table__).where(Event.session_id == _SID, Event.id > _LAST).order_by(Event.id),
              event_digest),
    "answer": (select(QuestionnaireResponse.__table__)
               .where(QuestionnaireResponse.session_id == _SID, QuestionnaireResponse.id > _LAST)
               .order_by(QuestionnaireResponse.id), answer_digest),
    "report": (select(LocationReport.__table__)
               .where(LocationReport.trial_id.in_(_TRIAL_IDS), LocationReport.id > _LAST)
               .order_by(LocationReport.id), report_digest),
}
_NEW_CHUNKS = (select(SampleChunk.id, SampleChunk.digest)
               .where(SampleChunk.trial_id.in_(_TRIAL_IDS), SampleChunk.id > _LAST).order_by(SampleChunk.id))


def _session_rows(tx: OrmSession, session_id: int, mark: SealMark) -> dict[str, dict[str, Any]]:
    """Digests of the session's records that are new or changed since ``mark``."""
    new: dict[str, dict[str, Any]] = {}
    trials = {}
    conn = tx.connection()
    # Core rows (attribute access by column name), not ORM objects: no identity map, and always what the
    # database holds now.
    for row in conn.execute(_TRIALS, {"session_id": session_id}):
        d = trial_digest(row)
        if mark.trials.get(row.id) != d:
            trials[str(row.id)] = d
    if trials:
        new["trial"] = trials
    for kind, (stmt, fn) in _NEW_ROWS.items():
        rows = {str(r.id): fn(r) for r in conn.execute(stmt, {"session_id": session_id, "last": mark.last[kind]})}
        if rows:
            new[kind] = rows
    chunks = {str(i): d for i, d in conn.execute(_NEW_CHUNKS, {"session_id": session_id,
                                                               "last": mark.last["chunk"]}).all()}
    if chunks:
        new["chunk"] = chunks
    return new


def seal_session(tx: OrmSession, session_id: int, mark: SealMark) -> dict[str, Any] | None:
    """Seal the session's records written or changed since ``mark`` in ``tx`` (one audit row; none if nothing
    changed). Call it in the transaction that wrote them, before it commits; once it has committed, advance
    the mark with ``mark.fold(returned)``."""
    tx.flush()
    new = _session_rows(tx, session_id, mark)
    if not new:
        return None
    append_audit(tx, SEAL_ACTION, entity="session", entity_id=session_id, details=new)
    return new


# ------------------------------------------------------------------------------------------ verifying


@dataclass(frozen=True)
class RecordProblem:
    kind: str  # trial | event | answer | report | chunk
    record_id: int
    change: str  # edited | deleted | inserted
    detail: str

    def line(self) -> str:
        return f"{_LABEL[self.kind]} {self.record_id} {self.change}: {self.detail}"


@dataclass(frozen=True)
class RecordsReport:
    """Result of :func:`verify_records`."""

    checked: dict[str, int]
    problems: tuple[RecordProblem, ...]
    notes: tuple[str, ...]
    erased: dict[str, int] = field(default_factory=dict)  # sealed records erased as their erasure row lists them

    @property
    def ok(self) -> bool:
        return not self.problems

    def summary(self, kinds: tuple[str, ...] = KINDS, counts: dict[str, int] | None = None) -> str:
        """``2 trials, 42 events, 3 answers, 1 location report, 8 sample chunks`` (the records checked, or
        ``counts``)."""
        return ", ".join(f"{n} {_LABEL[k]}{'' if n == 1 else 's'}" for k, n in (counts or self.checked).items()
                         if k in kinds)


@dataclass
class _Erasures:
    """What the erasures in the chain did, folded in chain order with the seals (see :func:`_sealed`)."""

    gone: dict[str, dict[int, int]] = field(default_factory=lambda: {k: {} for k in KINDS})  # id → erase row
    matched: dict[str, int] = field(default_factory=lambda: {k: 0 for k in KINDS})
    rows: list[int] = field(default_factory=list)
    problems: list[RecordProblem] = field(default_factory=list)


def _sealed(tx: OrmSession, erasures: _Erasures | None = None
            ) -> tuple[dict[str, dict[int, Any]], dict[int, dict[str, int]], dict[str, int]]:
    """Folded seals: digest per record, sealed id range per session, and the legacy (pre-coverage) ids.

    Folded in chain order with the erasures: an erasure takes each record it lists out of the sealed set
    (checking it erased what was sealed) into ``erasures.gone``; a later seal of the same id is a new record
    (SQLite gives the highest ids again once they were deleted), sealed afresh. An erased session's id range
    starts again too."""
    erasures = erasures if erasures is not None else _Erasures()
    sealed: dict[str, dict[int, Any]] = {k: {} for k in KINDS}
    where: dict[str, dict[int, int]] = {k: {} for k in KINDS}
    per_session: dict[int, dict[str, int]] = {}
    legacy = {k: 0 for k in KINDS}
    rows = tx.execute(select(AuditLog.id, AuditLog.action, AuditLog.entity_id, AuditLog.details)
                      .where(AuditLog.action.in_((SEAL_ACTION, COVERAGE_ACTION, ERASE_ACTION))).order_by(AuditLog.id))
    for audit_id, action, entity_id, details in rows:
        try:
            body = json.loads(details)
        except ValueError:
            continue  # an edited audit row: verify_audit names it
        if action == ERASE_ACTION:
            erasures.rows.append(audit_id)
            for kind in KINDS:
                for key, digest in ((body.get("erased") or {}).get(kind) or {}).items():
                    rid = int(key)
                    before = sealed[kind].pop(rid, None)
                    sealed_in = where[kind].pop(rid, None)
                    erasures.gone[kind][rid] = audit_id
                    if before is None:
                        continue  # never sealed (written before sealing existed): nothing to compare
                    if _same(digest, before):
                        erasures.matched[kind] += 1
                    else:
                        erasures.problems.append(RecordProblem(
                            kind, rid, "edited", f"erased in audit row {audit_id}, but what was erased differs "
                            f"from what audit row {sealed_in} sealed: it was changed before the erasure"))
            for sid in body.get("sessions") or ():
                per_session.pop(int(sid), None)
            continue
        if action == COVERAGE_ACTION:
            for k in KINDS:
                legacy[k] = max(legacy[k], int(body.get(k) or 0))
            continue
        sid = int(entity_id)
        last = per_session.setdefault(sid, {k: 0 for k in KINDS})
        for kind in KINDS:
            for key, digest in (body.get(kind) or {}).items():
                sealed[kind][int(key)] = digest
                where[kind][int(key)] = audit_id
                erasures.gone[kind].pop(int(key), None)  # a new record under an id an erasure freed
                last[kind] = max(last[kind], int(key))
    sealed["_where"] = where  # type: ignore[assignment]
    return sealed, per_session, legacy


def _iter(tx: OrmSession, stmt: Any) -> Iterator[Any]:
    yield from tx.execute(stmt.execution_options(yield_per=500))


def verify_records(tx: OrmSession) -> RecordsReport:
    """Recompute every covered record's digest and compare with the sealed ones (see module docstring)."""
    erasures = _Erasures()
    sealed, per_session, legacy = _sealed(tx, erasures)
    where = sealed.pop("_where")  # type: ignore[arg-type]
    status = dict(tx.execute(select(Session.id, Session.status)).all())
    trial_session = dict(tx.execute(select(Trial.id, Trial.session_id)).all())
    problems: list[RecordProblem] = []
    pending = 0
    legacy_seen = 0
    checked = {k: 0 for k in KINDS}

    def unsealed(kind: str, rid: int, session_id: int | None, what: str) -> None:
        nonlocal pending, legacy_seen
        if rid <= legacy[kind]:
            legacy_seen += 1
            return
        if session_id is not None and status.get(session_id) in UNFINISHED and \
                rid > per_session.get(session_id, {}).get(kind, 0):
            pending += 1
            return
        problems.append(RecordProblem(kind, rid, "inserted", f"{what} was never sealed: it was added outside "
                                                              "studyctl"))

    def compare(kind: str, rid: int, actual: Any, session_id: int | None, what: str) -> None:
        checked[kind] += 1
        if rid in erasures.gone[kind]:
            problems.append(RecordProblem(kind, rid, "inserted", f"{what} was erased in audit row "
                                          f"{erasures.gone[kind][rid]} but is stored again"))
            return
        expected = sealed[kind].pop(rid, None)
        if expected is None:
            unsealed(kind, rid, session_id, what)
            return
        if kind == "trial":
            parts = [name for name, a, e in zip(("fields", "outcome"), actual, expected, strict=True) if a != e]
            if parts:
                problems.append(RecordProblem(kind, rid, "edited", f"{what}: its {' and '.join(parts)} changed "
                                              f"since sealed in audit row {where[kind][rid]}"))
        elif actual != expected:
            problems.append(RecordProblem(kind, rid, "edited", f"{what} changed since sealed in audit row "
                                                               f"{where[kind][rid]}"))

    for t in _iter(tx, select(Trial.__table__).order_by(Trial.id)):
        compare("trial", t.id, trial_digest(t), t.session_id,
                f"(session {t.session_id}, plan position {t.plan_position}, {t.condition})")
    for e in _iter(tx, select(Event.__table__).order_by(Event.id)):
        compare("event", e.id, event_digest(e), e.session_id, f"(session {e.session_id} seq {e.seq}, {e.kind})")
    for a in _iter(tx, select(QuestionnaireResponse.__table__).order_by(QuestionnaireResponse.id)):
        compare("answer", a.id, answer_digest(a), a.session_id, f"({a.instrument} {a.item} = {a.code})")
    for r in _iter(tx, select(LocationReport.__table__).order_by(LocationReport.id)):
        compare("report", r.id, report_digest(r), trial_session.get(r.trial_id), f"(trial {r.trial_id})")
    for c in _iter(tx, select(SampleChunk.__table__).order_by(SampleChunk.id)):
        what = f"(trial {c.trial_id}, stream {c.stream}, chunk {c.chunk_index})"
        recomputed = stored_chunk_digest(c)
        if c.digest is not None and recomputed != c.digest and c.id in sealed["chunk"]:
            checked["chunk"] += 1
            sealed["chunk"].pop(c.id, None)
            problems.append(RecordProblem("chunk", c.id, "edited", f"{what}: its samples no longer match its digest"))
            continue
        compare("chunk", c.id, recomputed if c.digest is not None else None, trial_session.get(c.trial_id), what)
    for kind in KINDS:
        for rid in sorted(sealed[kind]):
            problems.append(RecordProblem(kind, rid, "deleted", f"sealed in audit row {where[kind][rid]} but no "
                                                                "longer stored"))
    problems += erasures.problems
    notes = []
    if any(erasures.matched.values()):
        rows = erasures.rows
        summary = ", ".join(f"{n} {_LABEL[k]}{'' if n == 1 else 's'}" for k, n in erasures.matched.items() if n)
        notes.append(f"erased at participants' request (audit row{'s' if len(rows) > 1 else ''} "
                     f"{', '.join(map(str, rows))}): {summary}; each matches its seal")
    if pending:
        notes.append(f"{pending} record(s) of unfinished sessions written after their last seal (pending: the next "
                     "resume seals them)")
    if legacy_seen:
        notes.append(f"{legacy_seen} record(s) written before this database was upgraded to sealed records "
                     "(not covered)")
    problems.sort(key=lambda p: (KINDS.index(p.kind), p.record_id))
    return RecordsReport(checked=checked, problems=tuple(problems), notes=tuple(notes),
                         erased={k: n for k, n in erasures.matched.items() if n})


def _same(erased: Any, sealed: Any) -> bool:
    # trial digests are [fields, outcome] lists in both; JSON keeps them lists
    return list(erased) == list(sealed) if isinstance(erased, list) else erased == sealed


__all__ = ["COVERAGE_ACTION", "ERASE_ACTION", "KINDS", "SEAL_ACTION", "RecordProblem", "RecordsReport", "SealMark",
           "answer_digest", "chunk_digest", "event_digest", "load_mark", "report_digest", "seal_session",
           "stored_chunk_digest", "trial_digest", "verify_records"]
