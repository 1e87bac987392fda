"""The repository API over the study database: what the rest of studyctl calls to read and write.

Every method that writes takes an optional ``tx`` (an ORM session from :meth:`StudyStore.in_transaction`)
so callers can group several changes atomically, e.g. "allocate the next counterbalancing slot, then
add the participant"; without ``tx`` each call is its own committed transaction. Objects returned are
plain ORM instances detached from any session (attributes stay readable; change data through these
methods, not by mutating the objects).

Changes to the study's structure (study, participants, sessions, trial status) are written to the
hash-chained audit log in the same transaction; high-volume rows (events, samples) are not.
"""

from __future__ import annotations

import contextlib
import hashlib
import secrets
from collections.abc import Iterator
from datetime import datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import select
from sqlalchemy.orm import Session as OrmSession

from studyctl import __version__
from studyctl.closing import Closeable
from studyctl.errors import NotFoundError, UsageError
from studyctl.store.audit import AuditReport, append_audit, verify_audit
from studyctl.store.db import Database
from studyctl.store.models import (
    PARTICIPANT_STATUSES,
    SESSION_STATUSES,
    TRIAL_STATUSES,
    AuditLog,
    Participant,
    Session,
    Study,
    Trial,
    utcnow,
)
from studyctl.store.records import load_mark, seal_session
from studyctl.store.session_records import SessionRecords
from studyctl.store.values import MAX_TEXT, StoredRow, check_choice, check_seed, check_text, require, schedule_sha256

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)

_TRIAL_FIELDS = frozenset(
    {"status", "timed_out", "started_at", "ended_at", "outcome", "invalid_reason", "placement", "time_limit_s"}
)
_SESSION_FIELDS = frozenset({"status", "ended_at", "resume_count", "seed", "site"})


class StudyStore(SessionRecords, Closeable):
    """Repository over one study database (SQLite file or PostgreSQL).

    Create with :meth:`open` / :meth:`create`, or wrap an existing :class:`Database`.
    """

    def __init__(self, db: Database) -> None:
        self.db = db

    # -- lifecycle --------------------------------------------------------------------------------
    @classmethod
    def open(cls, url: Any) -> StudyStore:
        """Open an existing database at schema head (raises SchemaVersionError otherwise)."""
        return cls(Database.open(url))

    @classmethod
    def create(cls, url: Any) -> StudyStore:
        """Create a new database (SQLite file with mode 0600) migrated to head."""
        return cls(Database.create(url))

    def close(self) -> None:
        self.db.close()

    # -- transactions -----------------------------------------------------------------------------
    def in_transaction(
        self, lock: str | None = None, *, durable: bool = True
    ) -> contextlib.AbstractContextManager[OrmSession]:
        """One atomic write transaction (see :meth:`Database.in_transaction`); pass it as ``tx=``."""
        return self.db.in_transaction(lock=lock, durable=durable)

    def reading(self) -> contextlib.AbstractContextManager[OrmSession]:
        """A read-only snapshot session."""
        return self.db.reading()

    @contextlib.contextmanager
    def _tx(self, tx: OrmSession | None, lock: str | None = None, durable: bool = True) -> Iterator[OrmSession]:
        if tx is not None:
            yield tx
            return
        with self.db.in_transaction(lock=lock, durable=durable) as s:
            yield s

    @contextlib.contextmanager
    def _record_tx(self, tx: OrmSession | None, session_id: Any, durable: bool = True) -> Iterator[OrmSession]:
        """A transaction that writes a session's records. Without the caller's ``tx`` (the library used
        directly, not the session engine) the records are sealed into the audit chain before it commits
        (:func:`~studyctl.store.records.seal_session`), so ``audit verify`` sees them as written by studyctl,
        not inserted behind its back; with ``tx`` the caller seals (the engine does, per transaction)."""
        if tx is not None:
            yield tx
            return
        with self.db.in_transaction(durable=durable) as s:
            yield s
            sid = session_id(s) if callable(session_id) else session_id
            if sid is not None:
                seal_session(s, int(sid), load_mark(s, int(sid)))

    # -- studies ----------------------------------------------------------------------------------
    def create_study(
        self,
        name: str,
        *,
        protocol_text: str | None = None,
        protocol_name: str | None = None,
        seed: int | None = None,
        tx: OrmSession | None = None,
    ) -> Study:
        """Create a study with a snapshot of its protocol text (and its sha256) and a master seed.

        ``seed`` defaults to 63 random bits from the OS; it is stored so schedules can be re-derived.
        """
        check_text(name, "study name")
        check_text(protocol_name, "protocol name", allow_none=True)
        seed = check_seed(seed, "study seed")
        if seed is None:
            seed = secrets.randbits(63)
        digest = None if protocol_text is None else hashlib.sha256(protocol_text.encode("utf-8")).hexdigest()
        with self._tx(tx, lock="study") as s:
            if s.scalar(select(Study.id).where(Study.name == name)) is not None:
                raise UsageError(f"the database already holds a study named {name!r}; choose another name")
            study = Study(name=name, protocol_name=protocol_name, protocol_text=protocol_text,
                          protocol_sha256=digest, seed=seed, studyctl_version=__version__, created_at=utcnow())
            s.add(study)
            s.flush()
            append_audit(s, "study.create", entity="study", entity_id=study.id,
                         details={"name": name, "protocol_name": protocol_name, "protocol_sha256": digest,
                                  "seed": seed, "studyctl_version": __version__})
        return study

    def get_study(self, name: str | None = None, *, tx: OrmSession | None = None) -> Study:
        """The study called ``name``; without a name, the only study in the database."""
        with self._read(tx) as s:
            if name is not None:
                study = s.scalar(select(Study).where(Study.name == name))
                if study is None:
                    names = ", ".join(repr(n) for n in s.scalars(select(Study.name).order_by(Study.name))) or "none"
                    raise NotFoundError(f"no study named {name!r} in this database; studies: {names}")
                return study
            studies = list(s.scalars(select(Study).order_by(Study.id).limit(2)))
        if not studies:
            raise NotFoundError("this database holds no study yet; create one with `studyctl init DIR`")
        if len(studies) > 1:
            raise UsageError("this database holds several studies; name one (e.g. --study NAME)")
        return studies[0]

    def list_studies(self) -> list[Study]:
        with self.reading() as s:
            return list(s.scalars(select(Study).order_by(Study.id)))

    @contextlib.contextmanager
    def _read(self, tx: OrmSession | None) -> Iterator[OrmSession]:
        if tx is not None:
            yield tx
            return
        with self.db.reading() as s:
            yield s

    # one read each: the row by id (NotFoundError if none), a parent's rows in creation order
    def _by_id(self, model: type[StoredRow], row_id: int, tx: OrmSession | None) -> StoredRow:
        with self._read(tx) as s:
            return require(s, model, row_id)

    def _children(self, model: type[StoredRow], parent: Any, parent_id: int, tx: OrmSession | None) -> list[StoredRow]:
        with self._read(tx) as s:
            return list(s.scalars(select(model).where(parent == parent_id).order_by(model.id)))

    # -- participants -----------------------------------------------------------------------------
    def add_participant(
        self,
        study_id: int,
        code: str,
        *,
        stratum: str | None = None,
        group: str | None = None,
        sequence_slot: int | None = None,
        schedule: Any = None,
        schedule_seed: int | None = None,
        schedule_algorithm_version: str | None = None,
        status: str = "enrolled",
        tx: OrmSession | None = None,
    ) -> Participant:
        """Enroll a participant under a pseudonymous ``code`` (unique within the study, stored verbatim).

        ``schedule`` is the expanded, ordered trial plan (JSON); its sha256 is stored beside it. To
        allocate ``sequence_slot`` race-free, open ``with store.in_transaction(lock="enroll:<study>") as tx``,
        read the taken slots, then call this with ``tx=tx``.
        """
        check_text(code, "participant code")
        check_text(stratum, "stratum", allow_none=True)
        check_text(group, "group", allow_none=True)
        check_text(schedule_algorithm_version, "schedule algorithm version", allow_none=True, max_len=64)
        check_choice(status, PARTICIPANT_STATUSES, "participant status")
        check_seed(schedule_seed, "schedule seed")
        if sequence_slot is not None and (isinstance(sequence_slot, bool) or not isinstance(sequence_slot, int)):
            raise UsageError(f"sequence slot must be an integer, got {sequence_slot!r}")
        digest = None if schedule is None else schedule_sha256(schedule)
        with self._tx(tx) as s:
            require(s, Study, study_id)
            clash = s.scalar(select(Participant.id).where(Participant.study_id == study_id, Participant.code == code))
            if clash is not None:
                raise UsageError(f"participant code {code!r} is already enrolled in this study; codes must be unique")
            p = Participant(study_id=study_id, code=code, stratum=stratum, group=group, sequence_slot=sequence_slot,
                            status=status, schedule=schedule, schedule_sha256=digest, schedule_seed=schedule_seed,
                            schedule_algorithm_version=schedule_algorithm_version, enrolled_at=utcnow())
            s.add(p)
            s.flush()
            append_audit(s, "participant.enroll", entity="participant", entity_id=p.id,
                         details={"study_id": study_id, "code": code, "stratum": stratum, "group": group,
                                  "sequence_slot": sequence_slot, "schedule_sha256": digest,
                                  "schedule_seed": schedule_seed,
                                  "schedule_algorithm_version": schedule_algorithm_version})
        return p

    def get_participant(self, study_id: int, code: str, *, tx: OrmSession | None = None) -> Participant:
        """The participant with ``code`` in the study (NotFoundError names the code)."""
        with self._read(tx) as s:
            p = s.scalar(select(Participant).where(Participant.study_id == study_id, Participant.code == code))
        if p is None:
            raise NotFoundError(f"no participant with code {code!r} in this study")
        return p

    def get_participant_by_id(self, participant_id: int, *, tx: OrmSession | None = None) -> Participant:
        return self._by_id(Participant, participant_id, tx)

    def list_participants(self, study_id: int, *, tx: OrmSession | None = None) -> list[Participant]:
        """All participants of a study in enrollment order."""
        return self._children(Participant, Participant.study_id, study_id, tx)

    def set_participant_status(
        self, participant_id: int, status: str, *, reason: str | None = None, tx: OrmSession | None = None
    ) -> Participant:
        """Change a participant's status (``withdrawn`` records the time and the reason)."""
        check_choice(status, PARTICIPANT_STATUSES, "participant status")
        with self._tx(tx) as s:
            p = require(s, Participant, participant_id)
            old = p.status
            p.status = status
            if status == "withdrawn":
                p.withdrawn_at = utcnow()
                p.withdrawal_reason = reason
            s.flush()
            append_audit(s, "participant.status", entity="participant", entity_id=p.id,
                         details={"from": old, "to": status, "reason": reason})
        return p

    # -- sessions ---------------------------------------------------------------------------------
    def start_session(
        self,
        participant_id: int,
        *,
        seed: int | None = None,
        site: str | None = None,
        tx: OrmSession | None = None,
    ) -> Session:
        """Open a new running session for a participant."""
        check_seed(seed, "session seed")
        check_text(site, "site", allow_none=True)
        with self._tx(tx) as s:
            require(s, Participant, participant_id)
            sess = Session(participant_id=participant_id, status="running", started_at=utcnow(), seed=seed,
                           resume_count=0, site=site)
            s.add(sess)
            s.flush()
            append_audit(s, "session.start", entity="session", entity_id=sess.id,
                         details={"participant_id": participant_id, "seed": seed, "site": site})
        return sess

    def get_session(self, session_id: int, *, tx: OrmSession | None = None) -> Session:
        return self._by_id(Session, session_id, tx)

    def list_sessions(self, participant_id: int, *, tx: OrmSession | None = None) -> list[Session]:
        return self._children(Session, Session.participant_id, participant_id, tx)

    def update_session(self, session_id: int, *, tx: OrmSession | None = None, **fields: Any) -> Session:
        """Change a session's ``status``, ``ended_at``, ``resume_count``, ``seed`` or ``site`` (audited)."""
        unknown = set(fields) - _SESSION_FIELDS
        if unknown:
            raise UsageError(f"cannot update session field(s) {sorted(unknown)}; allowed: {sorted(_SESSION_FIELDS)}")
        if "status" in fields:
            check_choice(fields["status"], SESSION_STATUSES, "session status")
        with self._tx(tx) as s:
            sess = require(s, Session, session_id)
            before = {k: getattr(sess, k) for k in fields}
            for k, v in fields.items():
                setattr(sess, k, v)
            s.flush()
            append_audit(s, "session.update", entity="session", entity_id=session_id,
                         details={"from": before, "to": fields})
        return sess

    # -- trials -----------------------------------------------------------------------------------
    def add_trial(
        self,
        session_id: int,
        *,
        plan_position: int,
        condition: str,
        block: int | None = None,
        repetition: int | None = None,
        placement: Any = None,
        time_limit_s: float | None = None,
        status: str = "planned",
        replaces_trial_id: int | None = None,
        started_at: datetime | None = None,
        tx: OrmSession | None = None,
    ) -> Trial:
        """Add a trial row for ``plan_position`` of the session's participant's schedule.

        A replacement for an invalid or aborted trial passes ``replaces_trial_id``; the old row stays.
        """
        check_text(condition, "condition")
        check_choice(status, TRIAL_STATUSES, "trial status")
        if time_limit_s is not None and not (time_limit_s > 0):
            raise UsageError(f"time_limit_s must be > 0, got {time_limit_s!r}")
        with self._record_tx(tx, session_id) as s:
            sess = require(s, Session, session_id)
            if replaces_trial_id is not None and s.get(Trial, replaces_trial_id) is None:
                raise NotFoundError(f"trial {replaces_trial_id} to replace does not exist")
            trial = Trial(session_id=session_id, participant_id=sess.participant_id, plan_position=plan_position,
                          condition=condition, block=block, repetition=repetition, placement=placement,
                          time_limit_s=time_limit_s, status=status, timed_out=False, started_at=started_at,
                          replaces_trial_id=replaces_trial_id)
            s.add(trial)
            s.flush()
            if replaces_trial_id is not None:
                append_audit(s, "trial.replace", entity="trial", entity_id=trial.id,
                             details={"replaces_trial_id": replaces_trial_id, "plan_position": plan_position})
        return trial

    def update_trial(self, trial_id: int, *, tx: OrmSession | None = None, **fields: Any) -> Trial:
        """Set trial fields (status, timed_out, started_at, ended_at, outcome, invalid_reason, …).

        Status changes are audited. The commit is fsynced (SQLite ``synchronous=FULL``), so a
        completed trial survives a crash right after this returns.
        """
        unknown = set(fields) - _TRIAL_FIELDS
        if unknown:
            raise UsageError(f"cannot update trial field(s) {sorted(unknown)}; allowed: {sorted(_TRIAL_FIELDS)}")
        if "status" in fields:
            check_choice(fields["status"], TRIAL_STATUSES, "trial status")
        with self._record_tx(tx, lambda s: require(s, Trial, trial_id).session_id) as s:
            trial = require(s, Trial, trial_id)
            old_status = trial.status
            for k, v in fields.items():
                setattr(trial, k, v)
            s.flush()
            if "status" in fields and fields["status"] != old_status:
                append_audit(s, "trial.status", entity="trial", entity_id=trial_id,
                             details={"from": old_status, "to": fields["status"],
                                      "invalid_reason": fields.get("invalid_reason")})
        return trial

    def get_trial(self, trial_id: int, *, tx: OrmSession | None = None) -> Trial:
        return self._by_id(Trial, trial_id, tx)

    def list_trials(
        self, *, session_id: int | None = None, participant_id: int | None = None, tx: OrmSession | None = None
    ) -> list[Trial]:
        """Trials of a session or a participant, in creation order."""
        stmt = select(Trial).order_by(Trial.id)
        if session_id is not None:
            stmt = stmt.where(Trial.session_id == session_id)
        if participant_id is not None:
            stmt = stmt.where(Trial.participant_id == participant_id)
        with self._read(tx) as s:
            return list(s.scalars(stmt))

    # -- audit ------------------------------------------------------------------------------------
    def audit(
        self, action: str, *, entity: str | None = None, entity_id: Any = None,
        details: dict[str, Any] | None = None, actor: str | None = None, tx: OrmSession | None = None,
    ) -> AuditLog:
        """Append a row to the hash-chained audit log (e.g. ``session.resume`` with the reason)."""
        with self._tx(tx) as s:
            return append_audit(s, action, entity=entity, entity_id=entity_id, details=details, actor=actor)

    def verify_audit(self) -> AuditReport:
        """Check the whole audit chain; see :func:`studyctl.store.audit.verify_audit`."""
        with self.reading() as s:
            return verify_audit(s)

    def audit_frame(self) -> pd.DataFrame:
        import pandas as pd

        cols = ["id", "at", "actor", "action", "entity", "entity_id", "details", "hash"]
        with self.reading() as s:
            rows = s.execute(select(*(getattr(AuditLog, c) for c in cols)).order_by(AuditLog.id)).all()
        return pd.DataFrame([tuple(r) for r in rows], columns=cols)


__all__ = ["MAX_TEXT", "StudyStore", "check_text", "schedule_sha256"]
