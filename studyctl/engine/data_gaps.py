"""What is missing from a study's data, for the coordinator (``studyctl status`` and the coordinator page).

Three kinds of gap, each counted from the store alone:

* **dropped samples**: a trial's loop ran ``ticks`` iterations (its outcome says so) and each writes one sample row;
  rows that never reached the store (a crash between flushes, a failed commit) are ``ticks`` minus the rows stored;
* **trials missing**: planned trials with no completed attempt once the participant's session has ended (completed,
  aborted, interrupted) or the participant withdrew; a session still running or paused is in progress, not missing;
* **answers missing**: questionnaire items the plan gives at the start and after each completed trial, without an
  answer, counted under the same rule.

Rehearsal sessions (``run --rehearse``) are not data and are left out, as in :mod:`studyctl.engine.progress`.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from studyctl.protocol.stored_plan import Schedule
from studyctl.store import StudyStore
from studyctl.store.enrollment import study_protocol
from studyctl.store.reader import StudyReader

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)

# a session in these states is still being run: what it has not done yet is not missing
_IN_PROGRESS = ("running", "paused")


@dataclass(frozen=True)
class Gap:
    """One gap: ``kind`` is dropped_samples, trial_missing or answers_missing; ``count`` rows, trials or items."""

    participant: str
    session_id: int | None
    trial_id: int | None
    condition: str | None
    kind: str
    count: int
    detail: str


@dataclass(frozen=True)
class DataGaps:
    """A study's gaps plus the totals they are measured against."""

    study: str
    trials_checked: int  # ended trial attempts with a loop (ticks known)
    ticks: int  # their loop iterations
    samples_stored: int  # sample rows of those trials in the store
    gaps: tuple[Gap, ...]

    COLUMNS = ("participant", "session_id", "trial_id", "condition", "kind", "count", "detail")

    def total(self, kind: str) -> int:
        return int(sum(g.count for g in self.gaps if g.kind == kind))

    def totals(self) -> dict[str, int]:
        return {"trials_checked": self.trials_checked, "ticks": self.ticks, "samples_stored": self.samples_stored,
                "dropped_samples": self.total("dropped_samples"), "trials_missing": self.total("trial_missing"),
                "answers_missing": self.total("answers_missing")}

    def to_frame(self) -> pd.DataFrame:
        import pandas as pd

        return pd.DataFrame([tuple(getattr(g, c) for c in self.COLUMNS) for g in self.gaps], columns=list(self.COLUMNS))


def data_gaps(store: StudyStore, study: str | None = None) -> DataGaps:
    """Dropped samples, missing trials and missing questionnaire answers of every participant of a study."""
    reader = StudyReader(store, study)
    # a study created without a protocol (a bare `init`) has no questionnaires and no manual conditions to know of
    protocol = study_protocol(reader.study) if reader.study.protocol_text else None
    items = {i.id: len(i.items) for i in protocol.instruments} if protocol else {}
    manual = {c.id for c in protocol.conditions if c.manual} if protocol else set()
    roster = reader.roster()
    people = roster.participants
    trials = sorted(roster.trials, key=lambda t: t.id)  # gaps are listed in the order the trials were run
    stored = reader.stored_sample_rows([t.id for t in trials])
    # an answer is counted once per item and context; one given outside any session is not a session's answer
    answers = {(a.participant_id, a.instrument, a.item, a.context) for a in reader.answer_rows()
               if a.session_id is not None}
    code = {p.id: p.code for p in people}
    gaps: list[Gap] = []
    checked = ticks_total = rows_total = 0
    for t in trials:
        ticks = t.outcome.get("ticks")
        if t.status == "running" or not isinstance(ticks, int) or t.condition in manual:
            continue
        rows = int(stored.get(t.id) or 0)
        checked, ticks_total, rows_total = checked + 1, ticks_total + ticks, rows_total + rows
        if ticks > rows:
            gaps.append(Gap(code[t.participant_id], t.session_id, t.id, t.condition, "dropped_samples", ticks - rows,
                            f"{ticks - rows} samples dropped ({rows} of {ticks} stored)"))
    latest = roster.latest_sessions()
    given = Counter(pid for pid, *_ in answers)
    given_by = Counter((pid, inst) for pid, inst, *_ in answers)
    for p in people:
        sess = latest.get(p.id)
        if not p.schedule or (p.status != "withdrawn" and (sess is None or sess.status in _IN_PROGRESS)):
            continue
        why = ("withdrew" if p.status == "withdrawn" else
               f"session {sess.status}" + (": resume it" if sess.status == "interrupted" else ""))
        schedule = Schedule.from_json(p.schedule)
        done = {t.plan_position for t in trials if t.participant_id == p.id and t.status == "completed"}
        expected: Counter[str] = Counter()
        if done:
            expected.update(schedule.questionnaires_start)
        not_done: dict[str, list[int]] = {}
        for e in schedule.entries:
            if e.trial in done:
                expected.update(e.questionnaires_after)
            else:
                not_done.setdefault(e.condition, []).append(e.trial)
        for cond, numbers in not_done.items():
            gaps.append(Gap(p.code, getattr(sess, "id", None), None, cond, "trial_missing", len(numbers),
                            f"{len(numbers)} trial{'s' if len(numbers) > 1 else ''} missing: planned "
                            f"{', '.join(map(str, numbers))} ({why})"))
        short = {inst: n * items.get(inst, 0) - given_by[(p.id, inst)] for inst, n in expected.items()}
        short = {k: v for k, v in short.items() if v > 0}
        if short:
            gaps.append(Gap(p.code, getattr(sess, "id", None), None, None, "answers_missing", sum(short.values()),
                            f"{sum(short.values())} answers missing: "
                            + ", ".join(f"{k} {v}" for k, v in sorted(short.items()))
                            + f" ({why}; {given[p.id]} stored)"))
    return DataGaps(study=reader.study.name, trials_checked=checked, ticks=ticks_total, samples_stored=rows_total,
                    gaps=tuple(gaps))


def gap_lines(gaps: DataGaps, shown: int = 10) -> list[str]:
    """Plain-text lines for ``studyctl status``: the totals, then up to ``shown`` gaps."""
    t = gaps.totals()
    lines = [f"data: {t['trials_checked']} trials checked: {t['samples_stored']} of {t['ticks']} loop samples stored "
             f"({t['dropped_samples']} dropped); missing: {t['trials_missing']} trials, "
             f"{t['answers_missing']} questionnaire answers"]
    for g in gaps.gaps[:shown]:
        where = (f"trial {g.trial_id}" if g.trial_id is not None else
                 f"session {g.session_id}" if g.session_id is not None else "no session")
        lines.append(f"  {g.participant} {where}{' ' + g.condition if g.condition else ''}: {g.detail}")
    if len(gaps.gaps) > shown:
        lines.append(f"  … {len(gaps.gaps) - shown} more (`studyctl status --json` lists them all)")
    return lines


def gaps_json(gaps: DataGaps) -> dict[str, Any]:
    frame = gaps.to_frame()
    return {"totals": gaps.totals(), "gaps": frame.astype(object).where(frame.notna(), None).to_dict("records")}


__all__ = ["DataGaps", "Gap", "data_gaps", "gap_lines", "gaps_json"]
