"""Study progress at a glance: what ``studyctl status`` shows (counts by status)."""

from __future__ import annotations

from dataclasses import dataclass, field

import pandas as pd
from sqlalchemy import func, select

from studyctl.store.models import (
    PARTICIPANT_STATUSES,
    SESSION_STATUSES,
    TRIAL_STATUSES,
    Participant,
    Session,
    Study,
    Trial,
)
from studyctl.store.repository import StudyStore


@dataclass(frozen=True)
class StudyStatus:
    """Counts of a study's participants, sessions and trials by status."""

    study: str
    protocol_name: str | None
    protocol_sha256: str | None
    seed: int
    database: str
    participants: dict[str, int] = field(default_factory=dict)
    sessions: dict[str, int] = field(default_factory=dict)
    trials: dict[str, int] = field(default_factory=dict)

    def to_frame(self) -> pd.DataFrame:
        """Columns ``entity``, ``status``, ``count``: one row per entity × status (zeros included)."""
        rows = [("participant", k, v) for k, v in self.participants.items()]
        rows += [("session", k, v) for k, v in self.sessions.items()]
        rows += [("trial", k, v) for k, v in self.trials.items()]
        return pd.DataFrame(rows, columns=["entity", "status", "count"])


def _counts(store: StudyStore, stmt, allowed: tuple[str, ...]) -> dict[str, int]:
    with store.reading() as s:
        found = dict(s.execute(stmt).all())
    return {k: int(found.get(k, 0)) for k in allowed}


def study_status(store: StudyStore, study: Study) -> StudyStatus:
    """Count the study's participants, sessions and trials by status."""
    participants = _counts(
        store,
        select(Participant.status, func.count()).where(Participant.study_id == study.id).group_by(Participant.status),
        PARTICIPANT_STATUSES,
    )
    sessions = _counts(
        store,
        select(Session.status, func.count()).join(Participant, Session.participant_id == Participant.id)
        .where(Participant.study_id == study.id).group_by(Session.status),
        SESSION_STATUSES,
    )
    trials = _counts(
        store,
        select(Trial.status, func.count()).join(Participant, Trial.participant_id == Participant.id)
        .where(Participant.study_id == study.id).group_by(Trial.status),
        TRIAL_STATUSES,
    )
    return StudyStatus(study=study.name, protocol_name=study.protocol_name, protocol_sha256=study.protocol_sha256,
                       seed=study.seed, database=store.db.describe(), participants=participants, sessions=sessions,
                       trials=trials)


__all__ = ["StudyStatus", "study_status"]
