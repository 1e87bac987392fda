"""SQLAlchemy 2 typed ORM models of the study database.

One database holds one or more studies (a workspace's SQLite file usually one; a shared PostgreSQL
database may hold several). The hierarchy is study → participant → session → trial, with events,
sample chunks, questionnaire responses and location reports hanging off sessions and trials, and an
append-only, hash-chained audit log beside them.

There is deliberately no column for names or contact data: participants are pseudonymous codes; the
optional identity key lives in a separate file (:mod:`studyctl.store.identity`).

The schema is created by the alembic migrations in ``migrations/``; a test compares these models with
the migrated schema on SQLite and PostgreSQL, so a model change needs a new revision.
"""

from __future__ import annotations

from datetime import UTC, datetime
from typing import Any

from sqlalchemy import (
    JSON,
    BigInteger,
    Boolean,
    CheckConstraint,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Text,
    UniqueConstraint,
)
from sqlalchemy.dialects.postgresql import BYTEA, JSONB
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column, relationship
from sqlalchemy.types import TypeDecorator

from studyctl.errors import UsageError

# Named constraints: alembic's SQLite batch mode needs names to alter tables later.
NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}

# BIGINT on PostgreSQL; INTEGER on SQLite so the key aliases the rowid and autoincrements.
IdType = BigInteger().with_variant(Integer(), "sqlite")
JsonType = JSON().with_variant(JSONB(), "postgresql")
BlobType = LargeBinary().with_variant(BYTEA(), "postgresql")

PARTICIPANT_STATUSES = ("enrolled", "active", "completed", "withdrawn")
SESSION_STATUSES = ("running", "paused", "completed", "aborted", "interrupted")
TRIAL_STATUSES = ("planned", "running", "completed", "aborted", "invalid")


def utcnow() -> datetime:
    """The current time, timezone-aware in UTC (the only kind of datetime the store keeps)."""
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """A timezone-aware UTC timestamp on every backend.

    SQLite has no time zones: values are normalised to UTC before they are written and marked UTC
    when read, so the same code sees the same aware datetimes on SQLite and PostgreSQL.
    """

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise UsageError(f"naive datetime {value!r} given to the store; pass a timezone-aware datetime")
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect: Any) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


def _in(column: str, values: tuple[str, ...]) -> str:
    return f"{column} IN ({', '.join(repr(v) for v in values)})"


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map = {
        datetime: UTCDateTime(),
        bytes: BlobType,
    }


class Study(Base):
    """A study: its protocol snapshot (text and sha256), master seed and the studyctl that created it."""

    __tablename__ = "study"

    id: Mapped[int] = mapped_column(IdType, primary_key=True)
    name: Mapped[str] = mapped_column(String(200), unique=True)
    protocol_name: Mapped[str | None] = mapped_column(String(200))
    protocol_text: Mapped[str | None] = mapped_column(Text)
    protocol_sha256: Mapped[str | None] = mapped_column(String(64))
    seed: Mapped[int] = mapped_column(BigInteger)
    studyctl_version: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)

    participants: Mapped[list[Participant]] = relationship(back_populates="study", order_by="Participant.id")


class Participant(Base):
    """A pseudonymous participant with the schedule (ordered trial plan) drawn at enrollment."""

    __tablename__ = "participant"
    __table_args__ = (
        UniqueConstraint("study_id", "code", name="uq_participant_study_code"),
        CheckConstraint(_in("status", PARTICIPANT_STATUSES), name="status"),
    )

    id: Mapped[int] = mapped_column(IdType, primary_key=True)
    study_id: Mapped[int] = mapped_column(ForeignKey("study.id"), index=True)
    code: Mapped[str] = mapped_column(String(200))
    stratum: Mapped[str | None] = mapped_column(String(200))
    group: Mapped[str | None] = mapped_column(String(200))
    sequence_slot: Mapped[int | None] = mapped_column(Integer)
    status: Mapped[str] = mapped_column(String(20), default="enrolled")
    schedule: Mapped[Any | None] = mapped_column(JsonType)
    schedule_sha256: Mapped[str | None] = mapped_column(String(64))
    schedule_seed: Mapped[int | None] = mapped_column(BigInteger)
    schedule_algorithm_version: Mapped[str | None] = mapped_column(String(64))
    enrolled_at: Mapped[datetime] = mapped_column(default=utcnow)
    withdrawn_at: Mapped[datetime | None] = mapped_column()
    withdrawal_reason: Mapped[str | None] = mapped_column(Text)

    study: Mapped[Study] = relationship(back_populates="participants")
    sessions: Mapped[list[Session]] = relationship(back_populates="participant", order_by="Session.id")


class Session(Base):
    """One sitting of a participant; ``resume_count`` counts resumptions after pauses or crashes."""

    __tablename__ = "session"
    __table_args__ = (CheckConstraint(_in("status", SESSION_STATUSES), name="status"),)

    id: Mapped[int] = mapped_column(IdType, primary_key=True)
    participant_id: Mapped[int] = mapped_column(ForeignKey("participant.id"), index=True)
    status: Mapped[str] = mapped_column(String(20), default="running")
    started_at: Mapped[datetime] = mapped_column(default=utcnow)
    ended_at: Mapped[datetime | None] = mapped_column()
    seed: Mapped[int | None] = mapped_column(BigInteger)
    resume_count: Mapped[int] = mapped_column(Integer, default=0)
    site: Mapped[str | None] = mapped_column(String(200))

    participant: Mapped[Participant] = relationship(back_populates="sessions")
    trials: Mapped[list[Trial]] = relationship(back_populates="session", order_by="Trial.id")


class Trial(Base):
    """One executed (or planned) trial at ``plan_position`` of the participant's schedule.

    A trial that has to be repeated is kept (status ``invalid`` or ``aborted``) and a new row with
    ``replaces_trial_id`` pointing at it takes its place, so nothing is ever overwritten.
    """

    __tablename__ = "trial"
    __table_args__ = (
        CheckConstraint(_in("status", TRIAL_STATUSES), name="status"),
        Index("ix_trial_participant_position", "participant_id", "plan_position"),
    )

    id: Mapped[int] = mapped_column(IdType, primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("session.id"), index=True)
    participant_id: Mapped[int] = mapped_column(ForeignKey("participant.id"))
    plan_position: Mapped[int] = mapped_column(Integer)
    condition: Mapped[str] = mapped_column(String(200))
    block: Mapped[int | None] = mapped_column(Integer)
    repetition: Mapped[int | None] = mapped_column(Integer)
    placement: Mapped[Any | None] = mapped_column(JsonType)
    time_limit_s: Mapped[float | None] = mapped_column(Float)
    status: Mapped[str] = mapped_column(String(20), default="planned")
    timed_out: Mapped[bool] = mapped_column(Boolean, default=False)
    started_at: Mapped[datetime | None] = mapped_column()
    ended_at: Mapped[datetime | None] = mapped_column()
    outcome: Mapped[Any | None] = mapped_column(JsonType)
    replaces_trial_id: Mapped[int | None] = mapped_column(ForeignKey("trial.id"))
    invalid_reason: Mapped[str | None] = mapped_column(Text)

    session: Mapped[Session] = relationship(back_populates="trials")


class Event(Base):
    """An append-only event of a session (``seq`` orders them within the session)."""

    __tablename__ = "event"
    __table_args__ = (UniqueConstraint("session_id", "seq", name="uq_event_session_seq"),)

    id: Mapped[int] = mapped_column(IdType, primary_key=True)
    session_id: Mapped[int] = mapped_column(ForeignKey("session.id"))
    trial_id: Mapped[int | None] = mapped_column(ForeignKey("trial.id"), index=True)
    seq: Mapped[int] = mapped_column(Integer)
    t_mono: Mapped[float] = mapped_column(Float)
    t_wall: Mapped[datetime] = mapped_column()
    kind: Mapped[str] = mapped_column(String(100))
    payload: Mapped[Any | None] = mapped_column(JsonType)


class SampleChunk(Base):
    """A block of consecutive high-rate samples of one stream of one trial.

    ``t`` holds ``n`` float64 timestamps (little-endian) and ``data`` the ``n × len(channels)`` values
    row-major in ``dtype`` (a numpy dtype string such as ``<f8``). One chunk is what one
    :class:`~studyctl.store.samples.SampleWriter` flush commits, so a crash loses at most the rows
    buffered since the last flush.
    """

    __tablename__ = "sample_chunk"
    __table_args__ = (
        UniqueConstraint("trial_id", "stream", "chunk_index", name="uq_sample_chunk_trial_stream_index"),
        CheckConstraint("n > 0", name="n_positive"),
    )

    id: Mapped[int] = mapped_column(IdType, primary_key=True)
    trial_id: Mapped[int] = mapped_column(ForeignKey("trial.id"))
    stream: Mapped[str] = mapped_column(String(100))
    chunk_index: Mapped[int] = mapped_column(Integer)
    t0: Mapped[float] = mapped_column(Float)
    t1: Mapped[float] = mapped_column(Float)
    n: Mapped[int] = mapped_column(Integer)
    channels: Mapped[Any] = mapped_column(JsonType)
    dtype: Mapped[str] = mapped_column(String(16))
    t: Mapped[bytes] = mapped_column(BlobType)
    data: Mapped[bytes] = mapped_column(BlobType)
    # sha256 of the chunk's key fields and both blobs (studyctl.store.records.chunk_digest), written with the
    # chunk; the session's record seals chain it into the audit log, `db check` recomputes it.
    digest: Mapped[str | None] = mapped_column(String(64))


class QuestionnaireResponse(Base):
    """One coded answer to one item of a versioned instrument (e.g. a Likert item coded 1–5)."""

    __tablename__ = "questionnaire_response"

    id: Mapped[int] = mapped_column(IdType, primary_key=True)
    participant_id: Mapped[int] = mapped_column(ForeignKey("participant.id"), index=True)
    session_id: Mapped[int | None] = mapped_column(ForeignKey("session.id"))
    trial_id: Mapped[int | None] = mapped_column(ForeignKey("trial.id"))
    instrument: Mapped[str] = mapped_column(String(200))
    instrument_version: Mapped[str] = mapped_column(String(64))
    item: Mapped[str] = mapped_column(String(200))
    code: Mapped[int] = mapped_column(Integer)
    answered_at: Mapped[datetime] = mapped_column(default=utcnow)
    context: Mapped[str | None] = mapped_column(String(200))


class LocationReport(Base):
    """A participant's report of where a target is (grid cell or position), scored when known."""

    __tablename__ = "location_report"

    id: Mapped[int] = mapped_column(IdType, primary_key=True)
    trial_id: Mapped[int] = mapped_column(ForeignKey("trial.id"), index=True)
    t: Mapped[float] = mapped_column(Float)
    payload: Mapped[Any] = mapped_column(JsonType)
    correct: Mapped[bool | None] = mapped_column(Boolean)


class DeviceCalibration(Base):
    """A device's zero/calibration, measured by ``studyctl device calibrate``; sessions that used it record its id
    in a ``device_calibration`` event."""

    __tablename__ = "device_calibration"

    id: Mapped[int] = mapped_column(IdType, primary_key=True)
    study_id: Mapped[int] = mapped_column(ForeignKey("study.id"), index=True)
    device: Mapped[str] = mapped_column(String(100))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    params: Mapped[Any] = mapped_column(JsonType)  # device parameters the calibration sets (applied to sessions)
    detail: Mapped[Any | None] = mapped_column(JsonType)  # identity, what was measured and how


class AuditLog(Base):
    """An append-only, hash-chained audit row: ``hash = sha256(prev_hash + canonical JSON of the row)``.

    ``details`` is kept as the canonical JSON text itself, so re-reading it never changes what was
    hashed (JSONB would reorder keys).
    """

    __tablename__ = "audit_log"

    id: Mapped[int] = mapped_column(IdType, primary_key=True, autoincrement=False)
    at: Mapped[str] = mapped_column(String(40))
    actor: Mapped[str] = mapped_column(String(200))
    action: Mapped[str] = mapped_column(String(100))
    entity: Mapped[str | None] = mapped_column(String(100))
    entity_id: Mapped[str | None] = mapped_column(String(200))
    details: Mapped[str] = mapped_column(Text)
    prev_hash: Mapped[str] = mapped_column(String(64))
    hash: Mapped[str] = mapped_column(String(64), unique=True)


class SessionLease(Base):
    """The one process allowed to write a session: taken atomically with the session's start or resume,
    refreshed by a heartbeat, deleted when the process lets go (a row left behind is a crashed owner)."""

    __tablename__ = "session_lease"

    session_id: Mapped[int] = mapped_column(IdType, ForeignKey("session.id"), primary_key=True,
                                            autoincrement=False)
    token: Mapped[str] = mapped_column(String(64))
    pid: Mapped[int] = mapped_column(Integer)
    host: Mapped[str] = mapped_column(String(200))
    acquired_at: Mapped[datetime] = mapped_column()
    heartbeat_at: Mapped[datetime] = mapped_column()


class ErasePermit(Base):
    """Lets the event rows of one session be deleted while it exists, naming the ``participant.erase`` audit row
    that lists them (the delete trigger checks both); written and removed inside the erasing transaction."""

    __tablename__ = "erase_permit"

    session_id: Mapped[int] = mapped_column(IdType, primary_key=True, autoincrement=False)
    audit_id: Mapped[int] = mapped_column(IdType)


class AuditHead(Base):
    """The single row holding the audit chain's length and last hash (detects a deleted tail)."""

    __tablename__ = "audit_head"
    __table_args__ = (CheckConstraint("id = 1", name="single_row"),)

    id: Mapped[int] = mapped_column(Integer, primary_key=True, autoincrement=False)
    count: Mapped[int] = mapped_column(BigInteger)
    hash: Mapped[str] = mapped_column(String(64))


__all__ = [
    "PARTICIPANT_STATUSES",
    "SESSION_STATUSES",
    "TRIAL_STATUSES",
    "AuditHead",
    "AuditLog",
    "Base",
    "ErasePermit",
    "Event",
    "LocationReport",
    "Participant",
    "QuestionnaireResponse",
    "SampleChunk",
    "Session",
    "SessionLease",
    "Study",
    "Trial",
    "utcnow",
]
