"""The participant view's two hooks into a session: a :class:`SessionUI` and a :class:`Participant` wrapper.

Both wrap what the session would use anyway (the coordinator's terminal UI, the person participant), so
the engine runs unchanged and records everything through its own paths:

* :class:`ViewUI` mirrors every prompt on the participant's screen. A participant's answer given in the
  view reaches the engine *as the terminal's answer*: the terminal's prompt takes it from the view through
  ``Terminal.answer_source`` and parses it with the same code as a typed one, so both produce the same
  records. Coordinator prompts (manual outcome, unpause, pause/abort/invalid keys) stay terminal-only.
* :class:`ViewParticipant` adds the view's trial requests (scan, report, finish) to the wrapped
  participant's actions, and drops the scene's latest frame into the hub's slot for the server to stream.
  Per tick that is one reference swap, one ``perf_counter`` call and a deque check: the loop never waits
  for the view.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import asdict
from typing import Any

import numpy as np

from studyctl.engine.clock import Clock
from studyctl.engine.person import report_spec
from studyctl.engine.plan import Instrument, Item, ReportSpec, Step
from studyctl.engine.ui import Control, ManualOutcome, SessionUI, TimerResult
from studyctl.plugins.interfaces import Action, Participant, TrialInfo
from studyctl.view.board import CoordinatorBoard
from studyctl.view.hub import FrameState, TrialView, ViewHub

_perf = time.perf_counter
_tuple_new = tuple.__new__  # a NamedTuple without its Python-level __new__ (the hot path)

# Frame-draw records per ``view_frames`` event (real-time conditions draw ~60 a second).
FRAMES_PER_EVENT = 600


class ViewParticipant(Participant):
    """Wraps the session's participant: the view's requests join its actions; frames go to the view."""

    def __init__(self, inner: Participant, hub: ViewHub) -> None:
        self.inner = inner
        self.hub = hub
        self.name = getattr(inner, "name", "person")
        self.virtual = bool(getattr(inner, "virtual", False))
        self.params = dict(getattr(inner, "params", {}) or {})
        self._seq = 0
        self._scans = 0
        self._prev: tuple[float, float] | None = None
        # Bound once: this wrapper's act runs every tick of a 1 kHz loop.
        self._hub = hub
        self._inbox = hub.inbox
        self._inner_act = inner.act

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self.inner.begin_trial(info, rng)
        spec = report_spec(info)
        requests = tuple(info.public.get("requests", ("report", "finish")))
        self.hub.begin_trial(TrialView(info.visual, requests, spec, info.time_limit_s))
        self.hub.update(
            visual=info.visual,
            requests=list(requests),
            report=_report_fields(spec),
        )
        self._scans = 0
        self._prev = None

    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        prev = self._prev
        self._prev = (t, _perf())
        if prev is not None:
            # The percept was made during the previous tick; its state belongs to that tick's time.
            frame = percept.get("view")
            if frame is not None:
                self._seq += 1
                self._hub.latest = _tuple_new(FrameState, (self._seq, prev[0], prev[1], "view", frame, self._scans))
            else:
                frame = percept.get("scan")
                if frame is not None:
                    self._seq += 1
                    self._scans += 1
                    self._hub.latest = _tuple_new(
                        FrameState, (self._seq, prev[0], prev[1], "scan", frame, self._scans)
                    )
        action = self._inner_act(t, percept)
        inbox = self._inbox
        if inbox:
            extra = []
            while inbox:
                try:
                    extra.append(inbox.popleft())
                except IndexError:  # emptied by the engine thread between the check and the pop
                    break
            self._count_on_terminal(extra)
            action = Action(action.inputs, tuple(action.requests) + tuple(extra))
        return action

    def _count_on_terminal(self, requests: list) -> None:
        # The coordinator's status line counts scans and reports; keep it true for the view's requests.
        ui = getattr(self.inner, "ui", None)
        for r in requests:
            attr = {"scan": "scans", "report": "reports"}.get(r.kind)
            if attr and ui is not None and isinstance(getattr(ui, attr, None), int):
                setattr(ui, attr, getattr(ui, attr) + 1)

    def answer(self, item: Mapping[str, Any], rng: np.random.Generator) -> int:
        return self.inner.answer(item, rng)

    def __getattr__(self, name: str) -> Any:
        # Anything else the engine asks of a participant (later additions, duck-typed extras) is the inner's.
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)


def _finite(value: float) -> float | None:
    return float(value) if value is not None and np.isfinite(value) else None


def _report_fields(spec: ReportSpec) -> dict[str, Any]:
    out = asdict(spec)
    out["hint"] = spec.describe() if spec.kind != "none" else ""
    return out


class ViewUI:
    """A :class:`~studyctl.engine.ui.SessionUI` that shows every prompt in the participant view too.

    Parameters
    ----------
    inner
        The UI the session would use without the view (the coordinator's terminal, or scripted answers).
    hub
        The view's shared state.
    recorder
        Where the view's log goes (``view_*`` events); written only from the engine's thread, between
        loop ticks or after a trial, never from a server thread.
    """

    def __init__(self, inner: SessionUI, hub: ViewHub, recorder: Any = None,
                 board: CoordinatorBoard | None = None) -> None:
        self.inner = inner
        self.hub = hub
        self.rec = recorder
        self.board = board  # the coordinator's page (condition codes allowed there), told of every step
        if board is not None and recorder is not None:
            board.bind(recorder)
        self._ticks = 0
        self._trial_tick0 = 0  # the count at the running trial's start (its own ticks: the page's samples behind)
        self.interactive = bool(getattr(inner, "interactive", False))
        self.controls = True  # the view's countdown needs trial_tick every tick
        self._hub = hub
        self._inner_tick = inner.trial_tick
        self._inner_poll = inner.poll_control
        term = getattr(inner, "term", None)
        # Only a terminal prompt can take an answer from elsewhere; scripted answers never wait for one.
        self._term = term if term is not None and hasattr(term, "answer_source") else None
        if self._term is not None:
            self._term.answer_source = hub.take_answer
        hub.answerable = self._term is not None
        self._trial_label: dict[str, Any] = {}
        self._step: Step | None = None

    # -- log ---------------------------------------------------------------------------------------
    def flush(self, trial_id: int | None = None, trial: TrialView | None = None, *, practice: bool = False) -> int:
        """Write the view's queued log (and a finished trial's frame log) as session events."""
        rows: list[tuple[str, dict[str, Any], float | None, int | None]] = []
        rows += [(kind, payload, None, None) for kind, payload in self.hub.drain_log()]
        if trial is not None:
            rows += _trial_rows(trial, trial_id, practice=practice)
        if self.rec is None or not rows:
            return 0
        for i, (kind, payload, t, tid) in enumerate(rows):
            self.rec.event(kind, payload, t=t, trial_id=tid, commit=i == len(rows) - 1)
        return len(rows)

    def _publish(self, step: Step | None, phase: str, **detail: Any) -> None:
        """Tell the coordinator's page where the session is (engine thread, between loop ticks); ``step`` None:
        the first step not done yet (breaks and questionnaires reach the UI without their step)."""
        if self.board is not None and self.rec is not None:
            self.board.publish(self.rec.state(), step, phase, **detail)

    def trial_event(self, t: float, kind: str, payload: Mapping[str, Any]) -> None:
        """A trial-loop event (faults, recoveries, safety limits): shown live on the coordinator's page."""
        if self.board is not None:
            self.board.trial_event(t, kind, payload)

    def _trial_id(self, step: Step) -> int | None:
        if self.rec is None:
            return None
        attempts = self.rec.state().attempts(step.position)
        return attempts[-1].trial_id if attempts else None

    # -- SessionUI ------------------------------------------------------------------------------------
    def message(self, text: str) -> None:
        self.flush()
        self.inner.message(text)

    def instructions(self, step: Step, text: str) -> None:
        self.flush()
        self._step = step
        if step.kind == "end":
            self._publish(step, "done")
            self.hub.show("done", text=text)
            self.inner.instructions(step, text)
            return
        title = self._practice_title() if step.kind == "familiarisation" else "Instructions"
        self._publish(step, "instructions")
        self.hub.show("instructions", prompt="ready", text=text, title=title, condition=step.condition)
        try:
            self.inner.instructions(step, text)
        finally:
            self._done_prompt("ready", step)

    def timer(self, title: str, duration_s: float, clock: Clock, *, can_end_early: bool, purpose: str) -> TimerResult:
        self.flush()
        # The engine's title names the condition ("Familiarisation: <label>"); the page gets a neutral one.
        page_title = "Break" if purpose == "break" else self._practice_title()
        self._publish(None, "timer", title=title, purpose=purpose, duration_s=float(duration_s))
        self.hub.show(
            "timer",
            title=page_title,
            duration_s=float(duration_s),
            purpose=purpose,
            started=self.hub.clock(),
            can_end_early=bool(can_end_early),
        )
        try:
            return self.inner.timer(title, duration_s, clock, can_end_early=can_end_early, purpose=purpose)
        finally:
            self.hub.show("waiting")

    def ask_item(
        self, instrument: Instrument, item: Item, number: int, context: Mapping[str, Any]
    ) -> tuple[int, float]:
        self.flush()
        self._publish(None, "item", instrument=instrument.id, item=item.id, number=number,
                      total=len(instrument.items))
        self.hub.show(
            "item",
            prompt="likert",
            codes=item.codes(),
            instrument=instrument.id,
            title=instrument.title,
            intro=instrument.instructions if number == 1 else "",
            number=number,
            total=len(instrument.items),
            item=item.id,
            text=item.text,
            scale=[{"code": p.code, "label": p.label} for p in item.scale],
        )
        try:
            code, rt = self.inner.ask_item(instrument, item, number, context)
        finally:
            prompt = self.hub.prompt
            self.hub.clear_prompt()
        source = "view" if prompt is not None and prompt.taken else "terminal"
        detail = {
            "instrument": instrument.id,
            "item": item.id,
            "code": int(code),
            "source": source,
            "position": context.get("position"),
        }
        if source == "view":
            detail["client"] = prompt.client
            detail["page_rt_s"] = prompt.page_rt_s
        self.hub.note("view_answer", detail)
        self.hub.show("waiting")
        self.flush()
        return code, rt

    def manual_outcome(self, step: Step, report: ReportSpec, clock: Clock) -> ManualOutcome:
        self.flush()
        self._step = step
        self._publish(step, "manual")
        self.hub.show("hands_on", trial=step.trial_index, label=self._page_label(step), condition=step.condition)
        try:
            return self.inner.manual_outcome(step, report, clock)
        finally:
            self.hub.show("waiting")

    def trial_begin(self, step: Step, time_limit_s: float) -> None:
        self.flush()
        practice = step.kind == "familiarisation"
        self._trial_label = {
            "trial": step.trial_index,
            "condition": step.condition,  # kept off the page by the hub; logged with the screen
            "label": self._page_label(step),
            "practice": practice,
            # The protocol's limit, not the engine's unattended cap: no limit, no countdown.
            "time_limit_s": _finite(step.duration_s) if step.duration_s and not practice else None,
        }
        self._step = step
        self._publish(step, "trial_ready")
        self.hub.show("trial_ready", prompt="start", **self._trial_label)
        try:
            self.inner.trial_begin(step, time_limit_s)
        finally:
            self._done_prompt("start", step)
        self._trial_tick0 = self._ticks
        self._publish(step, "practice" if practice else "trial")
        self.hub.show("trial", **self._trial_label)

    def trial_tick(self, t: float) -> None:
        self._inner_tick(t)
        self._ticks += 1  # the coordinator's page measures the loop rate from this count
        self._hub.tick = (t, _perf(), self._ticks, self._ticks - self._trial_tick0)

    def trial_end(self, step: Step, summary: Mapping[str, Any]) -> None:
        trial = self.hub.end_trial()
        self.hub.show(
            "trial_over",
            **self._trial_label,
            status=summary.get("status"),
            ended_by=summary.get("ended_by"),
            duration_s=summary.get("duration_s"),
            scans=summary.get("scans"),
            reports=summary.get("reports"),
        )
        practice = step.kind == "familiarisation"
        self._publish(step, "trial_over", status=summary.get("status"), ended_by=summary.get("ended_by"))
        self.flush(None if practice else self._trial_id(step), trial, practice=practice)
        self.inner.trial_end(step, summary)

    def poll_control(self) -> Control | None:
        return self._inner_poll()

    def wait_unpause(self) -> None:
        self._publish(self._step, "paused")
        self.hub.show("paused")
        self.flush()
        try:
            self.inner.wait_unpause()
        finally:
            self.hub.show("waiting")

    def close(self) -> None:
        try:
            self.flush()
        finally:
            if self._term is not None:
                self._term.answer_source = None
            self.inner.close()

    def __getattr__(self, name: str) -> Any:
        # SessionUI additions this wrapper does not know yet behave as the wrapped UI's.
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    # -- helpers --------------------------------------------------------------------------------------
    def _view_label(self, condition: str | None) -> str:
        """The protocol's neutral name of a condition for the participant ('' when it declares none)."""
        if condition is None or self.rec is None:
            return ""
        try:
            spec = self.rec.state().plan.conditions.get(condition)
        except AttributeError:
            return ""
        return str(getattr(spec, "view_label", "") or "")

    def _page_label(self, step: Step) -> str:
        """What the page's heading calls a trial: "Trial 3" (· the protocol's neutral label), never the code."""
        what = "Practice" if step.kind == "familiarisation" else f"Trial {step.trial_index}"
        extra = self._view_label(step.condition)
        return f"{what} · {extra}" if extra else what

    def _practice_title(self) -> str:
        step = self._step
        extra = self._view_label(step.condition) if step is not None else ""
        return f"Practice · {extra}" if extra else "Practice"

    def _done_prompt(self, kind: str, step: Step) -> None:
        prompt = self.hub.prompt
        self.hub.clear_prompt()
        if prompt is not None:
            self.hub.note(
                "view_answer",
                {"prompt": kind, "position": step.position, "source": "view" if prompt.taken else "terminal"},
            )


def _trial_rows(
    trial: TrialView, trial_id: int | None, *, practice: bool = False
) -> list[tuple[str, dict[str, Any], float | None, int | None]]:
    """What the participant saw in a trial (or practice) and when: each scan, real-time frames in batches.

    Times are trial (practice) times; practice rows carry ``"practice": true`` and no trial id."""
    # A frame drawn by several screens is logged once per screen (the log keeps the client).
    rows: list[tuple[str, dict[str, Any], float | None, int | None]] = []
    log = sorted(trial.log, key=lambda r: (r["drawn_t"], r["seq"]))
    scans = [r for r in log if r["source"] == "scan"]
    for r in scans:
        rows.append(
            (
                "view_scan_shown",
                {
                    "seq": r["seq"],
                    "state_t": r["state_t"],
                    "drawn_t": r["drawn_t"],
                    "latency_ms": round(r["latency_ms"], 3),
                    "client": r["client"],
                },
                r["drawn_t"],
                trial_id,
            )
        )
    frames = [r for r in log if r["source"] != "scan"]
    for i in range(0, len(frames), FRAMES_PER_EVENT):
        chunk = frames[i : i + FRAMES_PER_EVENT]
        lat = np.array([r["latency_ms"] for r in chunk])
        rows.append(
            (
                "view_frames",
                {
                    "n": len(chunk),
                    "seq": [r["seq"] for r in chunk],
                    "state_t": [round(r["state_t"], 6) for r in chunk],
                    "drawn_t": [round(r["drawn_t"], 6) for r in chunk],
                    "client": [r["client"] for r in chunk],
                    "latency_ms_p50": round(float(np.median(lat)), 3),
                    "latency_ms_max": round(float(lat.max()), 3),
                },
                chunk[0]["drawn_t"],
                trial_id,
            )
        )
    if practice:
        for _, payload, _, _ in rows:
            payload["practice"] = True
    return rows
