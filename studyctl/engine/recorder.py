"""What the session engine writes, as a small interface, and an in-memory implementation.

The engine never touches the database directly: it calls a :class:`Recorder`. Every method that records a
transition returns only after the record is durable (committed), so the engine can follow the rule
"record, then act". :class:`MemoryRecorder` keeps everything in lists (unit tests, dry runs);
:class:`studyctl.engine.store_recorder.StoreRecorder` writes to the study database.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

from studyctl.engine.plan import SessionPlan
from studyctl.errors import UnknownKeyError


@dataclass(frozen=True)
class TrialRecord:
    """One attempt at a planned trial step (a repeated trial has several attempts at one position)."""

    trial_id: int
    position: int
    attempt: int
    status: str
    reason: str = ""
    outcome: Mapping[str, Any] = field(default_factory=dict)
    condition: str | None = None


#: Event holding a virtual participant's memory (``Participant.memory``) at the end of a trial.
MEMORY_EVENT = "participant_memory"


@dataclass
class SessionState:
    """What is durably recorded about a session: enough to resume it."""

    session_id: int
    participant: str
    seed: int
    status: str  # created, running, interrupted, completed, aborted
    plan: SessionPlan
    completed: set[int] = field(default_factory=set)  # step positions done
    started: set[int] = field(default_factory=set)  # step positions entered at least once
    trials: list[TrialRecord] = field(default_factory=list)
    answers: dict[tuple[int, str], int] = field(default_factory=dict)  # (step position, item id) → code
    resumes: int = 0
    last_t: float = 0.0  # latest session-clock time recorded (a resumed clock continues from here)
    virtual: bool = True  # run by a virtual participant (a resume keeps the mode)
    rehearsal: bool = False  # a rehearsal on emulated hardware: recorded, never analysed
    memory: dict[str, Any] | None = None  # the participant's memory stored with its last finished trial

    def attempts(self, position: int) -> list[TrialRecord]:
        """Started attempts at the trial step ``position`` (planned rows are not attempts)."""
        return [t for t in self.trials if t.position == position and t.status != "planned"]

    def set_trial(
        self, trial_id: int, status: str, reason: str, outcome: Mapping[str, Any] | None = None
    ) -> bool:
        """Give trial ``trial_id`` a new status and reason (and outcome); False when there is no such trial."""
        for i, r in enumerate(self.trials):
            if r.trial_id == trial_id:
                self.trials[i] = replace(r, status=status, reason=reason,
                                         outcome=dict(outcome) if outcome is not None else r.outcome)
                return True
        return False


class SampleSink(Protocol):
    def write(self, t: float, values: Mapping[str, float]) -> None: ...

    def close(self) -> None:
        """Flush what is buffered; the trial's samples are durable afterwards."""


class Recorder(Protocol):
    """Durable record of one session. Methods return after the record is committed."""

    def state(self) -> SessionState: ...

    def event(
        self,
        kind: str,
        payload: Mapping[str, Any] | None = None,
        *,
        t: float | None = None,
        position: int | None = None,
        trial_id: int | None = None,
        commit: bool = True,
        durable: bool | None = None,
    ) -> None:
        """Append one event (``t``: session clock seconds; trial events: trial time).

        ``commit=False`` may buffer the event until the next committed record (high-rate, low-value
        events such as safety clamps inside a trial). ``durable`` forces (True) or skips (False) the
        power-cut-safe sync of the commit; None lets the recorder decide by kind.
        """

    def set_status(self, status: str, reason: str = "") -> None: ...

    def step_started(self, position: int, t: float) -> None: ...

    def step_completed(self, position: int, t: float, summary: Mapping[str, Any] | None = None) -> None: ...

    def trial_started(self, position: int, attempt: int, t: float, info: Mapping[str, Any]) -> int:
        """Enter the trial step and create the attempt record (status running) together; returns its id."""

    def trial_finished(
        self,
        trial_id: int,
        status: str,
        outcome: Mapping[str, Any],
        reports: list[Mapping[str, Any]],
        *,
        position: int,
        t: float,
        reason: str = "",
        complete_step: bool = True,
    ) -> None:
        """Store the attempt's outcome, reports and status and (optionally) mark its step done, atomically."""

    def mark_trial(self, trial_id: int, status: str, reason: str) -> None: ...

    def samples(self, trial_id: int, channels: list[str]) -> SampleSink: ...

    def answer(
        self, position: int, instrument: str, version: str, item: str, code: int, response_time_s: float | None
    ) -> None: ...

    def amend_plan(self, plan: SessionPlan, reason: str) -> None: ...

    def audit(self, action: str, detail: Mapping[str, Any]) -> None: ...


# ------------------------------------------------------------------------------------------------------
class _MemorySamples:
    def __init__(self, store: list[tuple[int, float, dict[str, float]]], trial_id: int) -> None:
        self._store = store
        self._trial = trial_id
        self._buf: list[tuple[int, float, dict[str, float]]] = []

    def write(self, t: float, values: Mapping[str, float]) -> None:
        self._buf.append((self._trial, t, dict(values)))

    def close(self) -> None:
        self._store.extend(self._buf)
        self._buf.clear()


class MemoryRecorder:
    """A :class:`Recorder` that keeps everything in memory (tests, dry runs)."""

    def __init__(self, plan: SessionPlan, *, participant: str = "P001", seed: int = 0, session_id: int = 1) -> None:
        self._state = SessionState(session_id, participant, seed, "created", plan)
        self.events: list[dict[str, Any]] = []
        self.outcomes: dict[int, dict[str, Any]] = {}
        self.reports: list[dict[str, Any]] = []
        self.sample_rows: list[tuple[int, float, dict[str, float]]] = []
        self.responses: list[dict[str, Any]] = []
        self.audits: list[dict[str, Any]] = []
        self._next_trial = 1

    def state(self) -> SessionState:
        return self._state

    def event(self, kind, payload=None, *, t=None, position=None, trial_id=None, commit=True, durable=None) -> None:
        if t is not None and trial_id is None:
            self._state.last_t = max(self._state.last_t, float(t))
        if kind == MEMORY_EVENT:
            self._state.memory = dict((payload or {}).get("memory") or {})
        self.events.append(
            {"kind": kind, "payload": dict(payload or {}), "t": t, "position": position, "trial_id": trial_id,
             "wall": time.time()}
        )

    def set_status(self, status: str, reason: str = "") -> None:
        self._state.status = status
        self.event("session_status", {"status": status, "reason": reason})

    def step_started(self, position: int, t: float) -> None:
        self._state.started.add(position)
        self.event("step_enter", {}, t=t, position=position)

    def step_completed(self, position: int, t: float, summary=None) -> None:
        self._state.completed.add(position)
        self.event("step_done", dict(summary or {}), t=t, position=position)

    def trial_started(self, position: int, attempt: int, t: float, info) -> int:
        tid = self._next_trial
        self._next_trial += 1
        cond = self._state.plan.step(position).condition
        self.step_started(position, t)
        self._state.trials.append(TrialRecord(tid, position, attempt, "running", condition=cond))
        self.event("trial_start", dict(info), t=t, position=position, trial_id=tid)
        return tid

    def _set_trial(self, trial_id: int, status: str, reason: str, outcome=None) -> None:
        if not self._state.set_trial(trial_id, status, reason, outcome):
            raise UnknownKeyError(f"no trial {trial_id} in this session")

    def trial_finished(self, trial_id, status, outcome, reports, *, position, t, reason="", complete_step=True):
        self._set_trial(trial_id, status, reason, outcome)
        self.outcomes[trial_id] = dict(outcome)
        for r in reports:
            self.reports.append({"trial_id": trial_id, **r})
        self.event("trial_end", {"status": status, "reason": reason, **outcome}, t=t, position=position,
                   trial_id=trial_id)
        if complete_step:
            self.step_completed(position, t, {"trial_id": trial_id, "status": status})

    def mark_trial(self, trial_id: int, status: str, reason: str) -> None:
        self._set_trial(trial_id, status, reason)
        self.event("trial_marked", {"status": status, "reason": reason}, trial_id=trial_id)

    def samples(self, trial_id: int, channels: list[str]) -> _MemorySamples:
        return _MemorySamples(self.sample_rows, trial_id)

    def answer(self, position, instrument, version, item, code, response_time_s) -> None:
        self._state.answers[(position, item)] = int(code)
        self.responses.append(
            {"position": position, "instrument": instrument, "version": version, "item": item, "code": int(code),
             "response_time_s": response_time_s}
        )

    def amend_plan(self, plan: SessionPlan, reason: str) -> None:
        self._state.plan = plan
        self.event("plan_amended", {"reason": reason, "steps": len(plan.steps)})

    def audit(self, action: str, detail) -> None:
        self.audits.append({"action": action, **dict(detail)})
        if action == "session_resumed":
            self._state.resumes += 1
