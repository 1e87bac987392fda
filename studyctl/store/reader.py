"""The read side of one stored study: typed rows of what the study database holds, read once.

Analysis, figures, calibration, study progress and the data-gap count read a stored study through
:class:`StudyReader` and nothing else (no SQL above the store: ``tests/architecture/test_read_side.py``). A
reader belongs to one open database and one study; everything except the samples is read in a single snapshot
the first time it is needed and kept for the reader's life, so a report that computes metrics and then draws
trace figures reads the study once. Progress and gap counts read the lighter :meth:`StudyReader.roster` afresh.

Rows are frozen dataclasses. JSON payloads (a trial's outcome and placement, an event's payload, a
session's plan) are handed on as they were stored: their meaning belongs to the layers that wrote them
(the engine's session plan, the scene's truth), which the store does not import.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from sqlalchemy import func, select

from studyctl.closing import Closeable
from studyctl.errors import UnknownKeyError
from studyctl.store.models import (
    Event,
    LocationReport,
    Participant,
    QuestionnaireResponse,
    SampleChunk,
    Session,
    Study,
    Trial,
)
from studyctl.store.repository import StudyStore
from studyctl.store.samples import DEFAULT_STREAM
from studyctl.store.status import rehearsal_session_ids

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)

#: Event kinds that carry a scene's hidden truth as built for the trial (``truth`` in older databases).
TRUTH_EVENTS = ("scene_truth", "truth")
#: Session events that carry the session plan; the last one (an amended plan) is the one that ran.
PLAN_EVENTS = ("session_plan", "plan_amended")

#: Columns of :meth:`StudyReader.answers` (questionnaire answers, in the order they were given).
ANSWER_COLUMNS = ("participant_id", "session_id", "trial_id", "instrument", "item", "code", "context")

JSON = Mapping[str, Any]
_EMPTY: JSON = MappingProxyType({})


def _frozen(payload: Mapping[str, Any] | None) -> JSON:
    return MappingProxyType(dict(payload)) if payload else _EMPTY


@dataclass(frozen=True)
class StudyInfo:
    """The study row: its name and the protocol it ran (YAML text as stored at creation)."""

    id: int
    name: str
    protocol_name: str | None
    protocol_text: str | None
    protocol_sha256: str | None
    seed: int


@dataclass(frozen=True)
class ParticipantRow:
    """One enrolled participant. ``group`` is the participant's group, else its stratum; ``schedule`` the trial plan
    drawn at enrollment as stored (:meth:`studyctl.protocol.stored_plan.Schedule.from_json` reads it), or None."""

    id: int
    code: str
    group: str | None
    stratum: str | None
    status: str
    schedule: JSON | None = None


@dataclass(frozen=True)
class EventRow:
    """One recorded event: session time ``t`` (monotonic seconds), kind and JSON payload."""

    session_id: int
    trial_id: int | None
    t: float
    kind: str
    payload: JSON


@dataclass(frozen=True)
class LocationReportRow:
    """A participant's location report (grid cell or position) at trial time ``t``."""

    trial_id: int
    t: float
    payload: JSON


@dataclass(frozen=True)
class SessionRow:
    """One session: its seed and the plan it ran (the last stored plan JSON; None when none was stored)."""

    id: int
    participant_id: int
    status: str
    seed: int
    plan_json: JSON | None


@dataclass(frozen=True)
class TrialRow:
    """One stored trial with its events and reports.

    ``step`` is the plan step the trial ran (a repeat of an aborted trial has the step of the trial it
    replaces), ``plan_position`` the schedule entry the attempt was recorded under; ``stored_truth`` is the
    scene's truth as the engine recorded it for this trial, or None when the database predates truth events (then
    the scene must be rebuilt from the session plan).
    """

    id: int
    session_id: int
    participant_id: int
    step: int
    condition: str
    repetition: int | None
    time_limit_s: float | None
    status: str
    invalid_reason: str | None
    outcome: JSON
    placement: JSON
    plan_position: int = 0
    events: tuple[EventRow, ...] = ()
    reports: tuple[LocationReportRow, ...] = ()

    @property
    def stored_truth(self) -> JSON | None:
        for ev in self.events:
            if ev.kind in TRUTH_EVENTS:
                return ev.payload
        return None


@dataclass(frozen=True)
class AnswerRow:
    """One questionnaire answer (the columns of :data:`ANSWER_COLUMNS`); ``session_id`` is None for an answer given
    outside a session."""

    participant_id: int
    session_id: int | None
    trial_id: int | None
    instrument: str
    item: str
    code: int
    context: str | None


@dataclass(frozen=True)
class StudyRoster:
    """Who takes part and what they ran, without events, reports or samples: what study progress and the data-gap
    count need, read in one transaction (a coordinator page asks for it again and again). Rehearsal sessions and
    their trials are left out. Sessions carry no plan (``plan_json`` None) and trials no events: the
    :class:`StudySnapshot` has those."""

    participants: tuple[ParticipantRow, ...]
    sessions: tuple[SessionRow, ...]  # by participant, then id
    trials: tuple[TrialRow, ...]  # by participant, session, then id

    def latest_sessions(self) -> dict[int, SessionRow]:
        """Each participant's last session (the highest id; sessions come by participant, then id)."""
        return {x.participant_id: x for x in self.sessions}


@dataclass(frozen=True)
class StudySnapshot:
    """Everything about one study except samples and answers, read in one transaction."""

    participants: tuple[ParticipantRow, ...]
    sessions: tuple[SessionRow, ...]
    trials: tuple[TrialRow, ...]  # by participant, session, then id
    participant_by_id: Mapping[int, ParticipantRow] = field(repr=False)
    session_by_id: Mapping[int, SessionRow] = field(repr=False)


class StudyReader(Closeable):
    """Read one study of an open :class:`StudyStore`; open with :meth:`open` or wrap a store you own.

    Parameters
    ----------
    store
        An open store. The reader closes it only when it opened it (:meth:`open`).
    study
        The study's name (None: the database's only study) or its row.
    """

    def __init__(self, store: StudyStore, study: str | Study | None = None, *, owns_store: bool = False) -> None:
        self.store = store
        row = study if isinstance(study, Study) else store.get_study(study)
        self.study = StudyInfo(
            id=int(row.id),
            name=row.name,
            protocol_name=row.protocol_name,
            protocol_text=row.protocol_text,
            protocol_sha256=row.protocol_sha256,
            seed=int(row.seed),
        )
        self._owns_store = owns_store

    @classmethod
    def open(
        cls, db: str | None = None, workspace: str | os.PathLike[str] | None = None, study: str | None = None
    ) -> StudyReader:
        """Open the database a command should use (``--db``, ``$STUDYCTL_DB``, the workspace) for reading.

        The study is ``study``, else the workspace's, else the database's only study.
        """
        from studyctl.store.workspace import resolve_database

        url, ws = resolve_database(db, workspace)
        store = StudyStore.open(url)
        try:
            return cls(store, study or (ws.study if ws is not None else None), owns_store=True)
        except BaseException:
            store.close()
            raise

    def close(self) -> None:
        if self._owns_store:
            self.store.close()

    @property
    def source(self) -> str:
        """Where the data come from, for tables and reports: the database and the study."""
        return f"{self.store.db.describe()} (study {self.study.name!r})"

    # -- the snapshot -----------------------------------------------------------------------------
    @cached_property
    def snapshot(self) -> StudySnapshot:
        """Participants, sessions and trials (with events and reports) of the study, read once. Rehearsal sessions
        (``studyctl run --rehearse``) are left out: they are recorded, never analysed."""
        with self.store.reading() as s:
            participants, sessions, trials = self._people(s)
            sids = [x.id for x in sessions]
            events = (
                s.execute(
                    select(Event.session_id, Event.trial_id, Event.t_mono, Event.kind, Event.payload)
                    .where(Event.session_id.in_(sids))
                    .where((Event.trial_id.is_not(None)) | Event.kind.in_(PLAN_EVENTS))
                    .order_by(Event.session_id, Event.seq)
                ).all()
                if sids
                else []
            )
            tids = [t.id for t in trials]
            reports = (
                s.execute(
                    select(LocationReport.trial_id, LocationReport.t, LocationReport.payload)
                    .where(LocationReport.trial_id.in_(tids))
                    .order_by(LocationReport.id)
                ).all()
                if tids
                else []
            )
        # rehearsals (emulated hardware, `studyctl run --rehearse`) are recorded in the study but are not data
        rehearsals = {sid for sid, tid, _t, kind, payload in events
                      if tid is None and kind == "session_plan" and (payload or {}).get("rehearsal")}
        if rehearsals:
            sessions = [x for x in sessions if x.id not in rehearsals]
            trials = [tr for tr in trials if tr.session_id not in rehearsals]
            events = [e for e in events if e[0] not in rehearsals]
        plans: dict[int, JSON] = {}
        trial_events: dict[int, list[EventRow]] = {}
        for sid, tid, t, kind, payload in events:
            if tid is None:
                plans[sid] = _frozen((payload or {})["plan"])  # the last (amended) plan wins
            else:
                trial_events.setdefault(tid, []).append(EventRow(sid, tid, float(t), kind, _frozen(payload)))
        trial_reports: dict[int, list[LocationReportRow]] = {}
        for tid, t, payload in reports:
            trial_reports.setdefault(tid, []).append(LocationReportRow(tid, float(t), _frozen(payload)))
        p_rows = tuple(_participant_row(p) for p in participants)
        s_rows = tuple(_session_row(x, plans.get(x.id)) for x in sessions)
        t_rows = tuple(_trial_row(tr, trial_events.get(tr.id, ()), trial_reports.get(tr.id, ())) for tr in trials)
        return StudySnapshot(
            participants=p_rows,
            sessions=s_rows,
            trials=t_rows,
            participant_by_id=MappingProxyType({p.id: p for p in p_rows}),
            session_by_id=MappingProxyType({x.id: x for x in s_rows}),
        )

    def _people(self, s) -> tuple[list[Participant], list[Session], list[Trial]]:  # noqa: ANN001 - a Session
        """The study's participants, their sessions and those sessions' trials (rehearsals included), in the open
        session ``s``."""
        participants = list(
            s.scalars(select(Participant).where(Participant.study_id == self.study.id).order_by(Participant.id))
        )
        pids = [p.id for p in participants]
        sessions = (
            # by participant first: with several workers, sessions (and their trials and answers) are
            # inserted in whichever order the workers start, and tables must not follow that race
            list(s.scalars(select(Session).where(Session.participant_id.in_(pids))
                           .order_by(Session.participant_id, Session.id)))
            if pids
            else []
        )
        sids = [x.id for x in sessions]
        trials = (
            list(s.scalars(select(Trial).where(Trial.session_id.in_(sids))
                           .order_by(Trial.participant_id, Trial.session_id, Trial.id))) if sids else []
        )
        return participants, sessions, trials

    def roster(self) -> StudyRoster:
        """Participants, sessions and trials as they stand now (read afresh on every call, unlike the snapshot: a
        running study's progress moves), rehearsals left out."""
        with self.store.reading() as s:
            participants, sessions, trials = self._people(s)
            rehearsals = rehearsal_session_ids(s, [x.id for x in sessions])
        return StudyRoster(
            participants=tuple(_participant_row(p) for p in participants),
            sessions=tuple(_session_row(x, None) for x in sessions if x.id not in rehearsals),
            trials=tuple(_trial_row(tr, (), ()) for tr in trials if tr.session_id not in rehearsals),
        )

    def stored_sample_rows(self, trial_ids: tuple[int, ...] | list[int], stream: str = DEFAULT_STREAM
                           ) -> dict[int, int]:
        """Sample rows stored per trial of ``trial_ids`` (in ``stream``); a trial without samples is left out."""
        ids = list(trial_ids)
        if not ids:
            return {}
        with self.store.reading() as s:
            rows = s.execute(select(SampleChunk.trial_id, func.sum(SampleChunk.n))
                             .where(SampleChunk.trial_id.in_(ids), SampleChunk.stream == stream)
                             .group_by(SampleChunk.trial_id)).all()
        return {int(tid): int(n or 0) for tid, n in rows}

    @property
    def participants(self) -> tuple[ParticipantRow, ...]:
        return self.snapshot.participants

    def session_events(self, kinds: tuple[str, ...] | list[str]) -> tuple[EventRow, ...]:
        """The study's events of the given kinds (e.g. ``session_plan``, ``population``), by session then order."""
        with self.store.reading() as s:
            rows = s.execute(
                select(Event.session_id, Event.trial_id, Event.t_mono, Event.kind, Event.payload)
                .join(Session, Session.id == Event.session_id)
                .join(Participant, Participant.id == Session.participant_id)
                .where(Participant.study_id == self.study.id, Event.kind.in_(tuple(kinds)))
                .order_by(Event.session_id, Event.seq)
            ).all()
        return tuple(EventRow(int(sid), tid, float(t or 0.0), kind, _frozen(payload))
                     for sid, tid, t, kind, payload in rows)

    @property
    def sessions(self) -> tuple[SessionRow, ...]:
        return self.snapshot.sessions

    @property
    def trials(self) -> tuple[TrialRow, ...]:
        """Every trial of the study (any status), by participant, session, then id."""
        return self.snapshot.trials

    def trial(self, trial_id: int) -> TrialRow:
        for tr in self.snapshot.trials:
            if tr.id == trial_id:
                return tr
        raise UnknownKeyError(f"no trial {trial_id} in this study")

    def first_completed(self, conditions: tuple[str, ...] | list[str]) -> dict[str, TrialRow]:
        """The first completed trial of each of ``conditions`` that has one, in :attr:`trials` order (the
        lowest-numbered participant's earliest: a figure's example trial stays the same as a study grows)."""
        wanted = set(conditions)
        out: dict[str, TrialRow] = {}
        for tr in self.snapshot.trials:
            if tr.status == "completed" and tr.condition in wanted:
                out.setdefault(tr.condition, tr)
        return out

    # -- samples and answers ----------------------------------------------------------------------
    def samples(self, trial_id: int, stream: str = DEFAULT_STREAM) -> pd.DataFrame:
        """A trial's samples (``t`` then one column per channel); read on every call, never kept."""
        return self.store.read_samples(trial_id, stream)

    def answer_rows(self) -> tuple[AnswerRow, ...]:
        """The study's questionnaire answers in the order given (by participant), rehearsal sessions' left out."""
        with self.store.reading() as s:
            pids = [int(p) for p in s.scalars(select(Participant.id).where(Participant.study_id == self.study.id))]
            if not pids:
                return ()
            rows = s.execute(
                select(*(getattr(QuestionnaireResponse, c) for c in ANSWER_COLUMNS))
                .where(QuestionnaireResponse.participant_id.in_(pids))
                .order_by(QuestionnaireResponse.participant_id, QuestionnaireResponse.id)
            ).all()
            rehearsals = rehearsal_session_ids(s, {r.session_id for r in rows if r.session_id is not None})
        return tuple(AnswerRow(*r) for r in rows if r.session_id not in rehearsals)

    def answers(self) -> pd.DataFrame:
        """The study's questionnaire answers in the order given, columns :data:`ANSWER_COLUMNS`."""
        import pandas as pd

        return pd.DataFrame([tuple(getattr(a, c) for c in ANSWER_COLUMNS) for a in self.answer_rows()],
                            columns=list(ANSWER_COLUMNS))


def _participant_row(p: Participant) -> ParticipantRow:
    return ParticipantRow(p.id, p.code, p.group or p.stratum, p.stratum, p.status,
                          None if p.schedule is None else _frozen(p.schedule))


def _session_row(x: Session, plan: JSON | None) -> SessionRow:
    return SessionRow(x.id, x.participant_id, x.status, int(x.seed or 0), plan)


def _trial_row(tr: Trial, events: tuple[EventRow, ...] | list[EventRow],
               reports: tuple[LocationReportRow, ...] | list[LocationReportRow]) -> TrialRow:
    return TrialRow(
        id=tr.id,
        session_id=tr.session_id,
        participant_id=tr.participant_id,
        step=int((tr.outcome or {}).get("step", tr.plan_position)),
        condition=tr.condition,
        repetition=tr.repetition,
        time_limit_s=tr.time_limit_s,
        status=tr.status,
        invalid_reason=tr.invalid_reason,
        outcome=_frozen(tr.outcome),
        placement=_frozen(tr.placement),
        plan_position=int(tr.plan_position),
        events=tuple(events),
        reports=tuple(reports),
    )


__all__ = [
    "ANSWER_COLUMNS",
    "AnswerRow",
    "PLAN_EVENTS",
    "TRUTH_EVENTS",
    "EventRow",
    "LocationReportRow",
    "ParticipantRow",
    "SessionRow",
    "StudyInfo",
    "StudyReader",
    "StudyRoster",
    "StudySnapshot",
    "TrialRow",
]
