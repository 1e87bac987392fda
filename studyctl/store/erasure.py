"""Erasing a withdrawn participant's recorded data without breaking the audit chain.

Events are append-only (database triggers) and every record is sealed in the hash-chained audit log
(:mod:`studyctl.store.records`), so a plain ``DELETE`` would be refused, and rows removed behind the triggers'
back read as tampering in ``studyctl audit verify``. An erasure is the one audited exception:

1. one ``participant.erase`` audit row (hash-chained like every other) lists the digest of every record it
   removes: trials, events, questionnaire answers, location reports and sample chunks, plus the sessions;
2. one ``erase_permit`` row per session names that audit row; the event table's delete trigger (migration 0004)
   lets a session's events go only while such a permit names a ``participant.erase`` row;
3. the records, the sessions and their leases are deleted, then the permits, all in the caller's transaction:
   a failure anywhere rolls everything back, nothing is half-erased.

:func:`~studyctl.store.records.verify_records` then reads a sealed record that is gone *and* listed in an
erasure with the digest it was sealed with as erased (a note, not a problem); one that differs from its seal
was edited before it was erased, one listed as erased but stored again was put back: both are problems.

Kept: the participant row (code, stratum, allocation slot, status ``withdrawn``: the counterbalancing and the
enrolment count depend on it) and the audit log itself. Notes typed about the participant's trials stay in
the audit log (its rows cannot be removed without breaking the chain), but leave the export with the trials.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from sqlalchemy import delete, select
from sqlalchemy.exc import DBAPIError
from sqlalchemy.orm import Session as OrmSession

from studyctl.errors import SessionError, StoreError
from studyctl.store.audit import append_audit
from studyctl.store.lease import current_holder, owner_alive
from studyctl.store.models import (
    ErasePermit,
    Event,
    LocationReport,
    Participant,
    QuestionnaireResponse,
    SampleChunk,
    Session,
    SessionLease,
    Trial,
)
from studyctl.store.records import (
    ERASE_ACTION,
    answer_digest,
    event_digest,
    report_digest,
    stored_chunk_digest,
    trial_digest,
)


@dataclass(frozen=True)
class Erasure:
    """What :func:`erase_participant_data` removed (counts per record kind) and the audit row that lists it."""

    audit_id: int
    sessions: tuple[int, ...]
    counts: dict[str, int]

    @property
    def total(self) -> int:
        return sum(self.counts.values())


def _digests(tx: OrmSession, p: Participant, sessions: list[int], trials: list[int]) -> dict[str, dict[str, Any]]:
    """Digest of every record to erase, by kind and id (the same digests the seals hold)."""
    out: dict[str, dict[str, Any]] = {}
    out["trial"] = {str(r.id): trial_digest(r) for r in tx.execute(
        select(Trial.__table__).where(Trial.participant_id == p.id).order_by(Trial.id))}
    out["event"] = {str(r.id): event_digest(r) for r in tx.execute(
        select(Event.__table__).where(Event.session_id.in_(sessions)).order_by(Event.id))}
    out["answer"] = {str(r.id): answer_digest(r) for r in tx.execute(
        select(QuestionnaireResponse.__table__).where(QuestionnaireResponse.participant_id == p.id)
        .order_by(QuestionnaireResponse.id))}
    out["report"] = {str(r.id): report_digest(r) for r in tx.execute(
        select(LocationReport.__table__).where(LocationReport.trial_id.in_(trials)).order_by(LocationReport.id))}
    # a chunk is sealed with the digest column written with it (None for chunks from before digests existed)
    out["chunk"] = {str(r.id): (stored_chunk_digest(r) if r.digest is not None else None) for r in tx.execute(
        select(SampleChunk.__table__).where(SampleChunk.trial_id.in_(trials)).order_by(SampleChunk.id))}
    return {k: v for k, v in out.items() if v}


def _check_leases(tx: OrmSession, db: Any, sessions: list[int]) -> list[int]:
    """Sessions whose lease a gone process left behind (removed with them); refuses a session still being run."""
    stale = []
    for sid in sessions:
        holder = current_holder(tx, sid)
        if holder is None:
            continue
        alive = owner_alive(db, holder)
        if alive is not False:
            raise SessionError(f"{holder.describe()}{'' if alive else ' (cannot tell whether it still runs)'}; "
                               "stop that session before erasing the participant's data")
        stale.append(sid)
    return stale


def has_data(tx: OrmSession, p: Participant) -> bool:
    """Does anything recorded of the participant remain (a session or an answer)?"""
    return (tx.scalar(select(Session.id).where(Session.participant_id == p.id).limit(1)) is not None
            or tx.scalar(select(QuestionnaireResponse.id).where(QuestionnaireResponse.participant_id == p.id)
                         .limit(1)) is not None)


def erase_participant_data(tx: OrmSession, db: Any, p: Participant, *, reason: str) -> Erasure:
    """Erase everything recorded of ``p`` in ``tx`` (see the module docstring); the caller commits or rolls back.

    Call it after the participant's open sessions were closed and sealed (:func:`~studyctl.store.coordination.
    withdraw` does), so the digests listed match the seals."""
    sessions = [int(s) for s in tx.scalars(select(Session.id).where(Session.participant_id == p.id)
                                           .order_by(Session.id))]
    trials = [int(t) for t in tx.scalars(select(Trial.id).where(Trial.participant_id == p.id))]
    stale = _check_leases(tx, db, sessions)
    erased = _digests(tx, p, sessions, trials)
    counts = {"session": len(sessions)} | {k: len(v) for k, v in erased.items()}
    entry = append_audit(tx, ERASE_ACTION, entity="participant", entity_id=p.id,
                         details={"code": p.code, "reason": reason, "sessions": sessions, "counts": counts,
                                  "erased": erased, "leases_left_behind": stale})
    try:
        tx.add_all([ErasePermit(session_id=sid, audit_id=entry.id) for sid in sessions])
        tx.flush()
        tx.execute(delete(LocationReport).where(LocationReport.trial_id.in_(trials)))
        tx.execute(delete(SampleChunk).where(SampleChunk.trial_id.in_(trials)))
        tx.execute(delete(QuestionnaireResponse).where(QuestionnaireResponse.participant_id == p.id))
        tx.execute(delete(Event).where(Event.session_id.in_(sessions)))
        # one statement for all of them: a repeat's replaces_trial_id points at a trial erased with it
        tx.execute(delete(Trial).where(Trial.participant_id == p.id))
        tx.execute(delete(SessionLease).where(SessionLease.session_id.in_(sessions)))
        tx.execute(delete(Session).where(Session.id.in_(sessions)))
        tx.execute(delete(ErasePermit).where(ErasePermit.session_id.in_(sessions)))
        tx.flush()
    except DBAPIError as exc:  # a table added later that still points at these rows: nothing is erased
        raise StoreError(f"erasing the data of {p.code} failed, nothing was erased: "
                         f"{str(exc.orig).splitlines()[0] if exc.orig else exc}") from None
    tx.expire_all()
    return Erasure(audit_id=int(entry.id), sessions=tuple(sessions), counts=counts)


__all__ = ["ERASE_ACTION", "Erasure", "erase_participant_data", "has_data"]
