"""The analysis view of a stored study: the trials that count, with their plan, truth and samples.

Built from a :class:`studyctl.store.reader.StudyReader` (never from SQL): the protocol and the session
plans are parsed once, the trial that counts for each plan step is chosen once (the last completed
attempt), and every trial's samples and truth are loaded on first use. Metrics and trace figures share
one :class:`StoredStudy` per report.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import pandas as pd

from studyctl.analysis.truth import SceneTruth
from studyctl.errors import AnalysisError, StudyctlError
from studyctl.store.reader import ParticipantRow, StudyReader, TrialRow

if TYPE_CHECKING:
    from studyctl.engine.plan import SessionPlan
    from studyctl.protocol import Protocol

#: Columns of :attr:`StoredStudy.responses`.
RESPONSE_COLUMNS = ("participant", "group", "condition", "instrument", "item", "code", "session_id")


@dataclass
class TrialView:
    """Everything recorded about one completed trial, with samples and truth loaded on first use."""

    row: TrialRow
    participant: str
    group: str | None
    session_seed: int
    plan: SessionPlan | None
    protocol: Protocol | None
    reader: StudyReader = field(repr=False)
    truths: SceneTruth = field(repr=False)
    #: Per-trial results that several metrics share (needle metrics, tissue scores, contact masks).
    cache: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def trial_id(self) -> int:
        return self.row.id

    @property
    def condition(self) -> str:
        return self.row.condition

    @property
    def repetition(self) -> int | None:
        return self.row.repetition

    @property
    def position(self) -> int:
        return self.row.step

    @property
    def time_limit_s(self) -> float | None:
        return self.row.time_limit_s

    @cached_property
    def events(self) -> list[dict[str, Any]]:
        """The trial's events as dicts: kind, t and payload."""
        return [{"kind": e.kind, "t": e.t, "payload": dict(e.payload)} for e in self.row.events]

    @cached_property
    def reports(self) -> list[dict[str, Any]]:
        """The trial's location reports: t and the stored payload's fields."""
        return [{"t": r.t, **r.payload} for r in self.row.reports]

    @cached_property
    def samples(self) -> pd.DataFrame:
        return self.reader.samples(self.row.id)

    @cached_property
    def truth(self) -> Mapping[str, Any]:
        return self.truths.of(self.row, self.plan, self.session_seed)

    def release_samples(self) -> None:
        """Forget the samples (what was computed from them stays in :attr:`cache`)."""
        self.__dict__.pop("samples", None)

    @property
    def duration_s(self) -> float:
        """The trial's duration: the loop's own end time, capped at the time limit."""
        d = self.row.outcome.get("duration_s")
        if d is None:
            for ev in self.row.events:
                if ev.kind == "trial_loop_end":
                    d = ev.t
        if d is None:
            raise AnalysisError("the trial recorded no duration")
        d = float(d)
        return min(d, float(self.time_limit_s)) if self.time_limit_s else d


class StoredStudy:
    """A stored study as analysis sees it (one per report; the reader stays open while it is used)."""

    def __init__(self, reader: StudyReader, truths: SceneTruth | None = None) -> None:
        self.reader = reader
        self.truths = truths or SceneTruth()

    @property
    def name(self) -> str:
        return self.reader.study.name

    @cached_property
    def protocol(self) -> Protocol | None:
        """The protocol the study ran, parsed from the text stored with it (None when none is stored)."""
        from studyctl.protocol import load_protocol_text

        text = self.reader.study.protocol_text
        return load_protocol_text(text, f"<protocol of study {self.name}>") if text else None

    @cached_property
    def plans(self) -> dict[int, SessionPlan]:
        """Each session's plan (the last amended one) by session id."""
        from studyctl.engine.plan import SessionPlan

        return {s.id: SessionPlan.from_json(s.plan_json) for s in self.reader.sessions if s.plan_json is not None}

    def _view(self, tr: TrialRow, p: ParticipantRow) -> TrialView:
        sess = self.reader.snapshot.session_by_id[tr.session_id]
        return TrialView(
            row=tr,
            participant=p.code,
            group=p.group,
            session_seed=sess.seed,
            plan=self.plans.get(sess.id),
            protocol=self.protocol,
            reader=self.reader,
            truths=self.truths,
        )

    @cached_property
    def _steps(self) -> tuple[list[TrialView], list[dict[str, Any]], dict[str, int]]:
        by_pid = self.reader.snapshot.participant_by_id
        by_step: dict[tuple[int, int], list[TrialRow]] = {}
        for tr in self.reader.trials:
            by_step.setdefault((tr.participant_id, tr.step), []).append(tr)
        views: list[TrialView] = []
        missing: list[dict[str, Any]] = []
        status_counts: dict[str, int] = {}
        for (pid, step), rows in by_step.items():
            p = by_pid[pid]
            for r in rows:
                status_counts[r.status] = status_counts.get(r.status, 0) + 1
            done = [r for r in rows if r.status == "completed"]
            if done:
                views.append(self._view(done[-1], p))
                continue
            last = rows[-1]
            why = {
                "planned": "planned but never run (session not finished)",
                "running": "interrupted while running (resume the session)",
            }.get(last.status, f"{last.status}: {last.invalid_reason or 'no reason recorded'}")
            missing.append(
                {
                    "participant": p.code,
                    "group": p.group,
                    "condition": last.condition,
                    "trial": str(last.id),
                    "metric": "*",
                    "reason": f"no completed trial at plan step {step}: {why}",
                }
            )
        return views, missing, status_counts

    @property
    def trials(self) -> list[TrialView]:
        """The trial that counts for each participant's plan step: its last completed attempt."""
        return self._steps[0]

    @property
    def missing(self) -> list[dict[str, Any]]:
        """Plan steps without a completed trial, as rows of the metric table's ``missing``."""
        return self._steps[1]

    @property
    def info(self) -> dict[str, Any]:
        counts = self._steps[2]
        return {
            "participants": len(self.reader.participants),
            "sessions": len(self.reader.sessions),
            "trials_completed": counts.get("completed", 0),
            "trials_other": {k: v for k, v in sorted(counts.items()) if k != "completed"},
        }

    def first_completed(self, conditions: Sequence[str]) -> dict[str, TrialView]:
        """The first completed trial (by id) of each condition, for trace figures."""
        by_pid = self.reader.snapshot.participant_by_id
        return {
            cond: self._view(tr, by_pid[tr.participant_id])
            for cond, tr in self.reader.first_completed(list(conditions)).items()
        }

    @cached_property
    def responses(self) -> pd.DataFrame:
        """Questionnaire answers with the condition they followed (None for end-of-study instruments)."""
        cols = list(RESPONSE_COLUMNS)
        frame = self.reader.answers()
        if frame.empty:
            return pd.DataFrame(columns=cols)
        by_pid = self.reader.snapshot.participant_by_id
        rows = []
        for r in frame.itertuples(index=False):
            p = by_pid[r.participant_id]
            condition = None
            plan = self.plans.get(r.session_id)
            if plan is not None and isinstance(r.context, str) and r.context.startswith("step:"):
                try:
                    condition = plan.step(int(r.context.split(":", 1)[1])).condition
                except StudyctlError:
                    condition = None
            rows.append(
                {
                    "participant": p.code,
                    "group": p.group,
                    "condition": condition,
                    "instrument": r.instrument,
                    "item": r.item,
                    "code": float(r.code),
                    "session_id": r.session_id,
                }
            )
        return pd.DataFrame(rows, columns=cols)
