"""Study progress at a glance: what ``studyctl status`` shows (counts by status)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from sqlalchemy import func, select

from studyctl.store.models import (
    PARTICIPANT_STATUSES,
    SESSION_STATUSES,
    TRIAL_STATUSES,
    Event,
    Participant,
    Session,
    Study,
    Trial,
)
from studyctl.store.repository import StudyStore

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)


@dataclass(frozen=True)
class StudyStatus:
    """Counts of a study's participants, sessions and trials by status."""

    study: str
    protocol_name: str | None
    protocol_sha256: str | None
    seed: int
    database: str
    participants: dict[str, int] = field(default_factory=dict)
    sessions: dict[str, int] = field(default_factory=dict)  # the study's data: rehearsals left out
    trials: dict[str, int] = field(default_factory=dict)
    rehearsal_sessions: dict[str, int] = field(default_factory=dict)  # `run --rehearse`: recorded, never data
    rehearsal_trials: dict[str, int] = field(default_factory=dict)

    def to_frame(self) -> pd.DataFrame:
        """Columns ``entity``, ``status``, ``count``: one row per entity × status (zeros included); rehearsals are
        the entities ``rehearsal_session`` and ``rehearsal_trial``."""
        import pandas as pd

        rows = [("participant", k, v) for k, v in self.participants.items()]
        rows += [("session", k, v) for k, v in self.sessions.items()]
        rows += [("trial", k, v) for k, v in self.trials.items()]
        rows += [("rehearsal_session", k, v) for k, v in self.rehearsal_sessions.items()]
        rows += [("rehearsal_trial", k, v) for k, v in self.rehearsal_trials.items()]
        return pd.DataFrame(rows, columns=["entity", "status", "count"])


def rehearsal_session_ids(s, session_ids) -> set[int]:
    """Which of ``session_ids`` are rehearsals (``studyctl run --rehearse``: flagged in their ``session_plan``
    event), read in the open session ``s``. Rehearsals are recorded in the study but are neither data, progress nor
    taking part."""
    ids = list(session_ids)
    if not ids:
        return set()
    heads = s.execute(select(Event.session_id, Event.payload).where(Event.session_id.in_(ids),
                                                                    Event.kind == "session_plan")).all()
    return {int(sid) for sid, payload in heads if (payload or {}).get("rehearsal")}


def _counts(rows, allowed: tuple[str, ...]) -> dict[str, int]:
    found: dict[str, int] = {}
    for status, n in rows:
        found[status] = found.get(status, 0) + int(n)
    return {k: int(found.get(k, 0)) for k in allowed}


def study_status(store: StudyStore, study: Study) -> StudyStatus:
    """Count the study's participants, sessions and trials by status; rehearsals are counted apart."""
    with store.reading() as s:
        participants = _counts(s.execute(select(Participant.status, func.count())
                                         .where(Participant.study_id == study.id).group_by(Participant.status)),
                               PARTICIPANT_STATUSES)
        by_session = s.execute(select(Session.id, Session.status).join(Participant, Session.participant_id ==
                                                                        Participant.id)
                               .where(Participant.study_id == study.id)).all()
        rehearsals = rehearsal_session_ids(s, [sid for sid, _ in by_session])
        trials = s.execute(select(Trial.session_id, Trial.status, func.count())
                           .join(Participant, Trial.participant_id == Participant.id)
                           .where(Participant.study_id == study.id).group_by(Trial.session_id, Trial.status)).all()
    return StudyStatus(
        study=study.name, protocol_name=study.protocol_name, protocol_sha256=study.protocol_sha256, seed=study.seed,
        database=store.db.describe(), participants=participants,
        sessions=_counts(((st, 1) for sid, st in by_session if sid not in rehearsals), SESSION_STATUSES),
        trials=_counts(((st, n) for sid, st, n in trials if sid not in rehearsals), TRIAL_STATUSES),
        rehearsal_sessions=_counts(((st, 1) for sid, st in by_session if sid in rehearsals), SESSION_STATUSES),
        rehearsal_trials=_counts(((st, n) for sid, st, n in trials if sid in rehearsals), TRIAL_STATUSES),
    )


__all__ = ["StudyStatus", "rehearsal_session_ids", "study_status"]
