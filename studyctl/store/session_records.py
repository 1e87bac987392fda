"""What a running session writes into the store: its events, sample streams, answers and location reports.

:class:`SessionRecords` is the part of :class:`~studyctl.store.repository.StudyStore` for these high-volume or
per-trial rows (the rest of the store is the study's structure: study, participants, sessions, trials). It
relies on the store's ``db``, ``reading()`` and ``_record_tx()`` (a transaction that seals the session's records
into the audit chain when the caller gives none).
"""

from __future__ import annotations

import contextlib
from collections.abc import Mapping, Sequence
from datetime import datetime
from typing import TYPE_CHECKING, Any

from sqlalchemy import func, insert, select
from sqlalchemy.orm import Session as OrmSession

from studyctl.errors import UsageError
from studyctl.store.models import Event, LocationReport, QuestionnaireResponse, Trial, utcnow
from studyctl.store.samples import DEFAULT_STREAM, SampleWriter, read_samples, sample_streams
from studyctl.store.values import check_text, require

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)

    from studyctl.store.db import Database


class SessionRecords:
    """Events, samples, questionnaire answers and location reports of sessions (mixed into the store)."""

    if TYPE_CHECKING:  # given by StudyStore
        db: Database

        def reading(self) -> contextlib.AbstractContextManager[OrmSession]: ...

        def _record_tx(self, tx: OrmSession | None, session_id: Any, durable: bool = True
                       ) -> contextlib.AbstractContextManager[OrmSession]: ...

    # -- events -----------------------------------------------------------------------------------
    def append_event(
        self,
        session_id: int,
        kind: str,
        payload: Mapping[str, Any] | None = None,
        *,
        t_mono: float,
        t_wall: datetime | None = None,
        trial_id: int | None = None,
        durable: bool = False,
        tx: OrmSession | None = None,
    ) -> int:
        """Append one event to a session's log; returns its ``seq`` (1, 2, … per session)."""
        return self.append_events(session_id, [(t_mono, kind, payload or {})], trial_id=trial_id, t_wall=t_wall,
                                  durable=durable, tx=tx)[0]

    def append_events(
        self,
        session_id: int,
        events: Sequence[tuple[float, str, Mapping[str, Any] | None]],
        *,
        trial_id: int | None = None,
        t_wall: datetime | None = None,
        durable: bool = False,
        tx: OrmSession | None = None,
    ) -> list[int]:
        """Append ``(t_mono, kind, payload)`` events in one transaction; returns their ``seq`` numbers.

        Like sample flushes, event commits survive the process being killed; pass ``durable=True`` to
        also fsync (power-cut safe) right away. Batch events that arrive together: one commit each.
        """
        if not events:
            return []
        wall = t_wall or utcnow()
        with self._record_tx(tx, session_id, durable=durable) as s:
            last = s.scalar(select(func.max(Event.seq)).where(Event.session_id == session_id))
            start = (last or 0) + 1
            rows = []
            for i, (t_mono, kind, payload) in enumerate(events):
                check_text(kind, "event kind", max_len=100)
                rows.append({"session_id": session_id, "trial_id": trial_id, "seq": start + i,
                             "t_mono": float(t_mono), "t_wall": wall, "kind": kind,
                             "payload": dict(payload) if payload is not None else None})
            s.execute(insert(Event), rows)
        return [r["seq"] for r in rows]

    def events_frame(self, session_id: int, trial_id: int | None = None) -> pd.DataFrame:
        """A session's events (optionally one trial's) with columns seq, trial_id, t_mono, t_wall, kind, payload."""
        import pandas as pd

        stmt = select(Event.seq, Event.trial_id, Event.t_mono, Event.t_wall, Event.kind, Event.payload).where(
            Event.session_id == session_id).order_by(Event.seq)
        if trial_id is not None:
            stmt = stmt.where(Event.trial_id == trial_id)
        with self.reading() as s:
            rows = s.execute(stmt).all()
        return pd.DataFrame([tuple(r) for r in rows],
                            columns=["seq", "trial_id", "t_mono", "t_wall", "kind", "payload"])

    # -- samples ----------------------------------------------------------------------------------
    def sample_writer(self, trial_id: int, channels: Sequence[str] | None = None, **kwargs: Any) -> SampleWriter:
        """A :class:`SampleWriter` for a trial (``stream``, ``dtype``, ``flush_interval_s``, ``guard``, ``seal`` as
        keywords). Its chunks are sealed into the audit chain as they are flushed unless ``seal=False`` (the
        session engine, which seals them with the trial's next record)."""
        kwargs.setdefault("seal", True)
        return SampleWriter(self.db, trial_id, channels, **kwargs)

    def read_samples(self, trial_id: int, stream: str = DEFAULT_STREAM) -> pd.DataFrame:
        """A trial's samples as a DataFrame (``t`` then one column per channel)."""
        return read_samples(self.db, trial_id, stream)

    def sample_streams(self, trial_id: int) -> list[str]:
        return sample_streams(self.db, trial_id)

    # -- answers and reports ----------------------------------------------------------------------
    def record_response(
        self,
        participant_id: int,
        *,
        instrument: str,
        instrument_version: str,
        item: str,
        code: int,
        session_id: int | None = None,
        trial_id: int | None = None,
        context: str | None = None,
        answered_at: datetime | None = None,
        tx: OrmSession | None = None,
    ) -> QuestionnaireResponse:
        """Store one coded questionnaire answer (the numeric code, never the label)."""
        check_text(instrument, "instrument")
        check_text(instrument_version, "instrument version", max_len=64)
        check_text(item, "questionnaire item")
        check_text(context, "response context", allow_none=True)
        if isinstance(code, bool) or not isinstance(code, int):
            raise UsageError(f"response code must be an integer, got {code!r}")
        with self._record_tx(tx, session_id) as s:
            r = QuestionnaireResponse(participant_id=participant_id, session_id=session_id, trial_id=trial_id,
                                      instrument=instrument, instrument_version=instrument_version, item=item,
                                      code=code, answered_at=answered_at or utcnow(), context=context)
            s.add(r)
            s.flush()
        return r

    def record_location_report(
        self, trial_id: int, *, t: float, payload: Mapping[str, Any], correct: bool | None = None,
        tx: OrmSession | None = None,
    ) -> LocationReport:
        """Store a participant's location report (grid cell or position) at trial time ``t``."""
        with self._record_tx(tx, lambda s: require(s, Trial, trial_id).session_id) as s:
            r = LocationReport(trial_id=trial_id, t=float(t), payload=dict(payload), correct=correct)
            s.add(r)
            s.flush()
        return r

    def responses_frame(self, participant_id: int | None = None) -> pd.DataFrame:
        import pandas as pd

        cols = ["participant_id", "session_id", "trial_id", "instrument", "instrument_version", "item", "code",
                "answered_at", "context"]
        stmt = select(*(getattr(QuestionnaireResponse, c) for c in cols)).order_by(QuestionnaireResponse.id)
        if participant_id is not None:
            stmt = stmt.where(QuestionnaireResponse.participant_id == participant_id)
        with self.reading() as s:
            rows = s.execute(stmt).all()
        return pd.DataFrame([tuple(r) for r in rows], columns=cols)

    def location_reports(self, trial_id: int) -> list[LocationReport]:
        with self.reading() as s:
            return list(s.scalars(select(LocationReport).where(LocationReport.trial_id == trial_id)
                                  .order_by(LocationReport.id)))
