"""Study progress for ``studyctl status``: per participant and condition, trials done, running and left,
and the counterbalancing balance achieved so far.

Balance counts participants who completed their session or are still taking part (not withdrawn), so a
drop-out does not leave a slot counted (see research notes on allocation).
"""

from __future__ import annotations

from collections import Counter, defaultdict
from dataclasses import dataclass
from typing import TYPE_CHECKING

from studyctl.protocol.stored_plan import Schedule
from studyctl.store import StudyStore
from studyctl.store.reader import StudyReader, TrialRow

if TYPE_CHECKING:  # pandas (+pyarrow, ~90 MB) is imported where a table is built, so commands that only
    import pandas as pd  # check or refuse stay small processes (issue 19: hostile input within 200 MB)


@dataclass(frozen=True)
class ProgressRow:
    participant: str
    stratum: str | None
    participant_status: str
    session_id: int | None
    session_status: str | None
    condition: str
    planned: int
    done: int
    running: int
    aborted: int
    invalid: int
    left: int


@dataclass(frozen=True)
class StudyProgress:
    """Rows per participant × condition plus balance counts (position × condition, and the first condition)."""

    study: str
    rows: tuple[ProgressRow, ...]
    position_counts: dict[str, dict[int, dict[str, int]]]  # stratum → position → condition → count

    COLUMNS = ("participant", "stratum", "participant_status", "session_id", "session_status", "condition",
               "planned", "done", "running", "aborted", "invalid", "left")

    @property
    def first_condition(self) -> dict[str, dict[str, int]]:
        """Stratum → condition → participants starting with it (position 1 of :attr:`position_counts`)."""
        return {k: dict(v.get(1, {})) for k, v in self.position_counts.items()}

    def to_frame(self) -> pd.DataFrame:
        import pandas as pd

        return pd.DataFrame([tuple(r.__dict__[c] for c in self.COLUMNS) for r in self.rows],
                            columns=list(self.COLUMNS))

    def balance_frame(self) -> pd.DataFrame:
        """Columns stratum, position, condition, participants (condition order position, 1-based)."""
        import pandas as pd

        out = [(s, pos, cond, n) for s, by_pos in self.position_counts.items()
               for pos, by_cond in sorted(by_pos.items()) for cond, n in sorted(by_cond.items())]
        return pd.DataFrame(out, columns=["stratum", "position", "condition", "participants"])

    def totals(self) -> dict[str, int]:
        keys = ("planned", "done", "running", "aborted", "invalid", "left")
        return {k: int(sum(getattr(r, k) for r in self.rows)) for k in keys}


def study_progress(store: StudyStore, study: str | None = None) -> StudyProgress:
    """Progress of every participant of a study, by condition, with the balance so far.

    ``done`` counts completed trials (invalid ones separately), ``left`` the planned trials whose plan
    position has no completed or invalid attempt yet (from the stored schedule when no session exists; none
    for a withdrawn participant, whose remaining trials were dropped).
    """
    reader = StudyReader(store, study)
    roster = reader.roster()  # rehearsals are not progress
    people = roster.participants
    latest = roster.latest_sessions()
    by_session: dict[int, list[TrialRow]] = defaultdict(list)
    for t in roster.trials:
        by_session[t.session_id].append(t)
    rows: list[ProgressRow] = []
    positions: dict[str, dict[int, Counter]] = {}
    for p in people:
        schedule = Schedule.from_json(p.schedule) if p.schedule else None
        planned = Counter(e.condition for e in schedule.entries) if schedule else Counter()
        sess = latest.get(p.id)
        mine = by_session.get(sess.id, []) if sess is not None else []
        finished_positions = {(t.condition, t.plan_position) for t in mine if t.status in ("completed", "invalid")}
        order = schedule.order if schedule else ()
        conditions = list(dict.fromkeys([*order, *planned, *(t.condition for t in mine)]))
        for cond in conditions:
            c_trials = [t for t in mine if t.condition == cond]
            done = sum(t.status == "completed" for t in c_trials)
            planned_n = planned.get(cond, 0)
            finished = sum(1 for (c, _pos) in finished_positions if c == cond)
            rows.append(ProgressRow(
                participant=p.code, stratum=p.stratum, participant_status=p.status,
                session_id=None if sess is None else sess.id, session_status=None if sess is None else sess.status,
                condition=cond, planned=planned_n, done=done,
                running=sum(t.status == "running" for t in c_trials),
                aborted=sum(t.status == "aborted" for t in c_trials),
                invalid=sum(t.status == "invalid" for t in c_trials),
                # a withdrawal drops the trials not run: none are left to do
                left=0 if p.status == "withdrawn" else max(planned_n - finished, 0),
            ))
        if schedule and p.status != "withdrawn":
            key = p.stratum or "all"
            for pos, cond in enumerate(schedule.order, start=1):
                positions.setdefault(key, {}).setdefault(pos, Counter())[cond] += 1
    return StudyProgress(
        study=reader.study.name,
        rows=tuple(rows),
        position_counts={k: {pos: dict(c) for pos, c in v.items()} for k, v in positions.items()},
    )


def progress_lines(progress: StudyProgress) -> list[str]:
    """Plain-text lines for ``studyctl status``: one line per participant, balance per stratum.

    Plain text (no markup), so codes are shown verbatim whatever characters they hold.
    """
    if not progress.rows:
        return ["progress: no participants enrolled yet"]
    lines = ["progress (done/planned per condition; running, left):"]
    by_person: dict[str, list[ProgressRow]] = {}
    for r in progress.rows:
        by_person.setdefault(r.participant, []).append(r)
    width = max(len(p) for p in by_person)
    for code, rows in by_person.items():
        first = rows[0]
        session = "no session" if first.session_id is None else f"session {first.session_id} {first.session_status}"
        if first.participant_status == "withdrawn":
            session = f"withdrawn, {session}"
        conds = "  ".join(
            f"{r.condition} {r.done}/{r.planned}" + (f" (+{r.invalid} invalid)" if r.invalid else "") for r in rows
        )
        running = sum(r.running for r in rows)
        left = sum(r.left for r in rows)
        lines.append(f"  {code:<{width}}  [{first.stratum or '-'}] {session}: {conds}; running {running}, left {left}")
    totals = progress.totals()
    lines.append(f"  total: {totals['done']} done, {totals['running']} running, {totals['left']} left, "
                 f"{totals['aborted']} aborted, {totals['invalid']} invalid")
    for stratum, first_counts in progress.first_condition.items():
        firsts = ", ".join(f"{c} {n}" for c, n in sorted(first_counts.items()))
        lines.append(f"  balance [{stratum}]: first condition: {firsts}")
        for pos, counts in sorted(progress.position_counts.get(stratum, {}).items()):
            lines.append(f"    position {pos}: " + ", ".join(f"{c} {n}" for c, n in sorted(counts.items())))
    return lines


def progress_json(progress: StudyProgress) -> dict:
    """The progress as JSON-ready data (``studyctl status --json``)."""
    frame = progress.to_frame()
    return {
        "rows": frame.astype(object).where(frame.notna(), None).to_dict("records"),
        "totals": progress.totals(),
        "first_condition": progress.first_condition,
        "position_counts": {s: {str(p): c for p, c in v.items()} for s, v in progress.position_counts.items()},
    }
