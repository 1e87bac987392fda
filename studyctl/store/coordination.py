"""What a coordinator records around the trials: consent, withdrawal and free-text notes.

Each is one row of the hash-chained audit log (``participant.consent``, ``participant.status`` with the
withdrawal, ``note``), written in one transaction with any change it makes, so it is covered by the chain
like every other record and needs no table of its own. Bad input (unknown or already withdrawn participant,
a note on a trial or session that does not exist, a consent version the protocol does not declare) raises
before anything is written. :func:`coordination_records` lists them for the export.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from sqlalchemy import func, select

from studyctl.errors import NotFoundError, UsageError
from studyctl.store.audit import append_audit
from studyctl.store.enrollment import OVER_TARGET_ACTION, study_protocol
from studyctl.store.erasure import ERASE_ACTION, erase_participant_data, has_data
from studyctl.store.models import AuditLog, Participant, Session, Trial
from studyctl.store.models import utcnow as _utcnow
from studyctl.store.records import load_mark, seal_session
from studyctl.suggest import nearest

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)

MAX_TEXT = 4000
RECORD_ACTIONS = ("participant.consent", "participant.status", "note", ERASE_ACTION, OVER_TARGET_ACTION)
# sessions a withdrawal ends: they cannot be resumed afterwards
_OPEN_SESSIONS = ("running", "paused", "interrupted")


@dataclass(frozen=True)
class Withdrawal:
    """What :func:`withdraw` did: the participant, the trials done and dropped, the sessions it closed."""

    code: str
    reason: str
    trials_done: int
    trials_dropped: int
    sessions_closed: tuple[int, ...]
    slot_freed: bool  # the protocol gives a withdrawn participant's slot to the next enrollee
    keep_data: bool
    erased: dict[str, int] | None = None  # records erased per kind (trial, event, answer, report, chunk, session)

    def to_frame(self) -> pd.DataFrame:
        import pandas as pd

        return pd.DataFrame([{"code": self.code, "reason": self.reason, "trials_done": self.trials_done,
                              "trials_dropped": self.trials_dropped, "sessions_closed": len(self.sessions_closed),
                              "slot_freed": self.slot_freed, "keep_data": self.keep_data,
                              "records_erased": sum((self.erased or {}).values())}])


def _text(value: str, what: str) -> str:
    text = (value or "").strip()
    if not text:
        raise UsageError(f"{what} is empty; give it as text")
    if len(text) > MAX_TEXT:
        raise UsageError(f"{what} has {len(text)} characters; at most {MAX_TEXT} are allowed")
    return text


def _participant(tx: Any, study: Any, code: str) -> Participant:
    p = tx.scalar(select(Participant).where(Participant.study_id == study.id, Participant.code == code))
    if p is None:
        codes = list(tx.scalars(select(Participant.code).where(Participant.study_id == study.id)))
        hint = nearest(code, codes)
        raise NotFoundError(f"no participant with code {code!r} in study {study.name!r}"
                            + (f"; did you mean {hint!r}?" if hint else "; `studyctl status` lists them"))
    return p


def withdraw(store: Any, code: str, *, reason: str, keep_data: bool = True, study: str | None = None) -> Withdrawal:
    """Withdraw a participant: no further sessions, open sessions closed (aborted), audited with the reason.

    Their planned trials that were not run are dropped; with ``participants.replace_withdrawn`` their
    allocation slot goes to the next enrollee. Recorded data are kept (``keep_data``), or erased
    (``keep_data=False``: :mod:`studyctl.store.erasure`, one ``participant.erase`` audit row listing the digest of
    every record removed, so ``audit verify`` still passes and reports the erasure). A participant who withdrew
    earlier with their data kept can ask for the erasure later: ``keep_data=False`` on them erases only.
    Everything happens in one transaction: on any error nothing is written.
    """
    why = _text(reason, "the withdrawal reason")
    target = store.get_study(study)
    protocol = study_protocol(target)
    with store.in_transaction() as tx:
        p = _participant(tx, target, code)
        if p.status == "withdrawn":
            when = p.withdrawn_at.isoformat(timespec="seconds") if p.withdrawn_at else "earlier"
            if keep_data:
                raise UsageError(f"participant {code} already withdrew ({when}: {p.withdrawal_reason or 'no reason'})"
                                 "; nothing to do (add --delete-data to erase what was recorded of them)")
            if not has_data(tx, p):
                raise UsageError(f"participant {code} already withdrew ({when}) and nothing recorded of them is "
                                 "left to erase; nothing to do")
            erasure = erase_participant_data(tx, store.db, p, reason=why)
            return Withdrawal(code=code, reason=why, trials_done=0, trials_dropped=0, sessions_closed=(),
                              slot_freed=bool(protocol.participants.replace_withdrawn), keep_data=False,
                              erased=erasure.counts)
        planned = len((p.schedule or {}).get("entries", ())) if isinstance(p.schedule, dict) else 0
        done = tx.scalar(select(func.count()).select_from(Trial).where(Trial.participant_id == p.id,
                                                                   Trial.status == "completed")) or 0
        closed = []
        for sess in tx.scalars(select(Session).where(Session.participant_id == p.id,
                                                     Session.status.in_(_OPEN_SESSIONS))):
            before = sess.status
            sess.status, sess.ended_at = "aborted", _utcnow()
            closed.append(sess.id)
            tx.flush()
            append_audit(tx, "session.update", entity="session", entity_id=sess.id,
                         details={"from": {"status": before}, "to": {"status": "aborted"},
                                  "reason": f"participant withdrew: {why}"})
            # the closed session's records are kept as they stand: seal what was still pending (a trial cut
            # short by a crash), else `audit verify` would take them for records inserted behind studyctl's back
            seal_session(tx, sess.id, load_mark(tx, sess.id))
        old = p.status
        p.status, p.withdrawn_at, p.withdrawal_reason = "withdrawn", _utcnow(), why
        tx.flush()
        pid = p.id
        append_audit(tx, "participant.status", entity="participant", entity_id=pid,
                     details={"from": old, "to": "withdrawn", "reason": why, "code": code, "keep_data": keep_data,
                              "trials_done": int(done), "trials_dropped": max(0, planned - int(done)),
                              "sessions_closed": list(closed),
                              "slot_freed": bool(protocol.participants.replace_withdrawn)})
        erased = None if keep_data else erase_participant_data(tx, store.db, p, reason=why).counts
        return Withdrawal(code=code, reason=why, trials_done=int(done), trials_dropped=max(0, planned - int(done)),
                          sessions_closed=tuple(closed), slot_freed=bool(protocol.participants.replace_withdrawn),
                          keep_data=keep_data, erased=erased)


def record_consent(store: Any, code: str, *, version: str, study: str | None = None) -> dict[str, Any]:
    """Record that a participant consented on consent-form ``version`` (must match the protocol's, if declared)."""
    given = _text(version, "the consent version")
    target = store.get_study(study)
    declared = study_protocol(target).study.consent_version
    if declared is not None and given != declared:
        raise UsageError(f"consent version {given!r} does not match the protocol's consent_version {declared!r}; "
                         f"record the version the participant signed, or update the protocol")
    with store.in_transaction() as tx:
        p = _participant(tx, target, code)
        if p.status == "withdrawn":
            raise UsageError(f"participant {code} has withdrawn; consent is not recorded after a withdrawal")
        details = {"code": code, "version": given}
        append_audit(tx, "participant.consent", entity="participant", entity_id=p.id, details=details)
    return details


def add_note(store: Any, text: str, *, session: int | None = None, trial: int | None = None,
             study: str | None = None) -> dict[str, Any]:
    """A free-text note on a session, a trial or (neither given) the study; audited."""
    body = _text(text, "the note")
    if session is not None and trial is not None:
        raise UsageError("give --session or --trial, not both (a trial names its session)")
    target = store.get_study(study)
    with store.in_transaction() as tx:
        entity, entity_id, details = "study", target.id, {"text": body}
        if trial is not None:
            row = _of_study(tx, Trial, trial, target, "`studyctl export` lists trial ids")
            entity, entity_id = "trial", trial
            details.update(trial_id=trial, session_id=row.session_id)
        elif session is not None:
            _of_study(tx, Session, session, target, "`studyctl status` lists them")
            entity, entity_id = "session", session
            details["session_id"] = session
        append_audit(tx, "note", entity=entity, entity_id=entity_id, details=details)
    return details


def _of_study(tx: Any, model: Any, key: int, target: Any, hint: str) -> Any:
    """The trial or session ``key`` if one of ``target``'s participants has it, else NotFoundError with ``hint``."""
    row = tx.scalar(select(model).join(Participant, model.participant_id == Participant.id)
                    .where(model.id == key, Participant.study_id == target.id))
    if row is None:
        raise NotFoundError(f"no {model.__tablename__} {key} in study {target.name!r}; {hint}")
    return row


RECORD_COLUMNS = {
    "at": ("Wall-clock time of the record (UTC, ISO 8601)", "", "datetime"),
    "actor": ("Who recorded it (STUDYCTL_ACTOR or the OS user)", "", "string"),
    "record": ("consent, withdrawal, erasure (the participant's recorded data deleted at their request), note, or "
               "over_target (enrolled past the target size on purpose, --over-target)", "", "string"),
    "participant": ("Pseudonymous participant code (consent, withdrawal, erasure, over_target)", "", "string"),
    "session_id": ("Session the note is about", "", "integer"),
    "trial_id": ("Trial attempt the note is about", "", "integer"),
    "consent_version": ("Consent-form version the participant signed", "", "string"),
    "text": ("The note, the withdrawal or erasure reason, or the target an over_target enrollment passed", "",
             "string"),
}


def coordination_records(tx: Any, study: Any) -> list[list[Any]]:
    """Consent, withdrawal, erasure, note and over-target rows of a study (audit-log order), columns as
    :data:`RECORD_COLUMNS`."""
    codes = {pid: code for pid, code in tx.execute(select(Participant.id, Participant.code)
                                                   .where(Participant.study_id == study.id))}
    trials = {tid for (tid,) in tx.execute(select(Trial.id).where(Trial.participant_id.in_(list(codes))))}
    sessions = {sid for (sid,) in tx.execute(select(Session.id).where(Session.participant_id.in_(list(codes))))}
    audit = [(a, json.loads(a.details or "{}")) for a in tx.scalars(
        select(AuditLog).where(AuditLog.action.in_(RECORD_ACTIONS)).order_by(AuditLog.id))]
    # SQLite gives an erased session's (trial's) id to the next new one: a note written before the erasure
    # that listed its session is about the erased one, not about today's holder of the id
    erased_until: dict[int, int] = {}
    for a, d in audit:
        if a.action == ERASE_ACTION:
            for sid in d.get("sessions") or ():
                erased_until[int(sid)] = a.id
    rows = []
    for a, d in audit:
        if a.action == "note":
            current = d.get("session_id") is None or a.id > erased_until.get(int(d["session_id"]), 0)
            ok = (a.entity == "study" and str(a.entity_id) == str(study.id)) or current and (
                d.get("trial_id") in trials or d.get("session_id") in sessions)
            if ok:
                rows.append([a.at, a.actor, "note", None, d.get("session_id"), d.get("trial_id"), None, d.get("text")])
        elif a.entity_id is not None and int(a.entity_id) in codes:
            if a.action == "participant.consent":
                rows.append([a.at, a.actor, "consent", codes[int(a.entity_id)], None, None, d.get("version"), None])
            elif a.action == OVER_TARGET_ACTION:
                rows.append([a.at, a.actor, "over_target", codes[int(a.entity_id)], None, None, None, d.get("target")])
            elif a.action == ERASE_ACTION:
                rows.append([a.at, a.actor, "erasure", codes[int(a.entity_id)], None, None, None, d.get("reason")])
            elif d.get("to") == "withdrawn":
                rows.append([a.at, a.actor, "withdrawal", codes[int(a.entity_id)], None, None, None, d.get("reason")])
    return rows
