"""The session state machine: run (or resume) a stored plan step by step.

instructions → familiarisation (timer, may end early) → trial (hard time limit, scans, reports) → break
→ questionnaire after a block or condition → … → end-of-study questionnaire → done.

Rules the runner keeps:

* **Record, then act.** Entering a step is committed before the step begins; a step's results and its
  completion are committed together. A crash at any instant therefore leaves every step either done
  (with all of its results) or not done.
* **One row per attempt.** A trial that is interrupted (crash, SIGKILL, power loss, Ctrl-C, device
  fault, coordinator abort or pause) keeps its record, status ``aborted``; the protocol's policy then
  repeats it at the same plan position (``repeat``: same placement, same random streams) or marks it
  invalid and appends a replacement after the last trial of its block (``invalidate_and_append``).
* **Answers are committed one by one**, so a resumed questionnaire asks only what is unanswered.
* **Devices end in their safe state** whatever happens (the trial loop commands it; the device is closed
  in a ``finally``).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import pandas as pd

from studyctl.engine.clock import Clock, RealClock, SimulatedClock
from studyctl.engine.factory import (
    MANUAL_TOUCH_DEVICE,
    EntryPointFactory,
    PluginFactory,
    build_controller,
    build_device,
    build_scene,
    controller_needs,
)
from studyctl.engine.plan import ConditionSpec, SessionPlan, Step
from studyctl.engine.recorder import MEMORY_EVENT, Recorder, SessionState
from studyctl.engine.seeding import TrialStreams, person_rng, trial_streams
from studyctl.engine.servo import ServoProcess, ServoSpec
from studyctl.engine.trial_loop import TrialOutcome, run_trial
from studyctl.engine.ui import Control, ManualOutcome, SessionUI
from studyctl.errors import DeviceError, InvalidAnswer, SessionError, SessionInterrupted, StudyctlError, UsageError
from studyctl.plugins.interfaces import Participant, TrialInfo

# A trial without a time limit (completion time is the measure) still needs an end when nobody can stop it:
# virtual and scripted runs stop such a trial here and record it as timed out.
UNATTENDED_TRIAL_CAP_S = 1800.0
INTERRUPTED_REASON = "interrupted: the session stopped during this trial (crash, kill or power loss)"
ProgressFn = Callable[[int, int, Step], None]


@dataclass(frozen=True)
class SessionResult:
    """How a run of :func:`run_session` / :class:`SessionRunner` ended."""

    session_id: int
    participant: str
    status: str
    steps_done: int
    steps_total: int
    trials_completed: int
    trials_aborted: int
    trials_invalid: int
    answers: int
    resumes: int

    COLUMNS = (
        "session_id", "participant", "status", "steps_done", "steps_total", "trials_completed",
        "trials_aborted", "trials_invalid", "answers", "resumes",
    )

    def to_frame(self) -> pd.DataFrame:
        return pd.DataFrame([asdict(self)], columns=list(self.COLUMNS))


def condition_rate(cond: ConditionSpec, factory: PluginFactory) -> float:
    """The loop rate a condition runs at: its own ``rate_hz``, else its controller's, else 50 Hz."""
    if cond.rate_hz:
        return float(cond.rate_hz)
    if cond.controller and not cond.manual:
        return float(getattr(factory.load("controller", cond.controller), "rate_hz", 50.0) or 50.0)
    return 50.0


class SessionRunner:
    """Runs one session's stored plan through a :class:`Recorder`.

    Parameters
    ----------
    recorder
        Durable record of the session (in memory or the study database).
    ui
        Prompts (terminal, scripted file, or a virtual participant's answers).
    participant
        The Participant plugin acting in trials (a person's terminal input, or a virtual one).
    clock
        :class:`~studyctl.engine.clock.RealClock` for people, ``SimulatedClock`` for virtual runs.
    factory
        Where scene, controller and device plugins come from.
    virtual
        True when the participant is virtual: simulated devices; in manual conditions it palpates the
        scene with the simulated bare finger (``direct_touch``) and its reports become the manual outcome.
    progress
        Called after each step with (steps done, steps in plan, step).
    servo
        Run hardware trials in the servo process (:mod:`studyctl.engine.servo`). None (default): yes when
        plugins come from entry points (the child loads them by name); False: in this process.
    device_ref
        ``{"plugin": …, "params": …}`` replacing the plan's hardware device (a rehearsal's emulator). With a
        ``world`` (``run --rehearse --virtual``) the virtual participant acts on this emulated hardware instead of
        the simulated device: its hand is in the emulator's world (:mod:`studyctl.devices.world`).
    virtual_ref
        ``{"plugin": …, "params": …}`` of the virtual participant, rebuilt in the servo process when it acts on
        emulated hardware (the same person: params, session seed and memory travel with each trial).
    """

    def __init__(
        self,
        recorder: Recorder,
        *,
        ui: SessionUI,
        participant: Participant,
        clock: Clock,
        factory: PluginFactory,
        virtual: bool,
        progress: ProgressFn | None = None,
        servo: bool | None = None,
        device_ref: Mapping[str, Any] | None = None,
        virtual_ref: Mapping[str, Any] | None = None,
    ) -> None:
        self.rec = recorder
        self.virtual_ref = dict(virtual_ref) if virtual_ref else None
        self.servo = servo
        self.device_override = dict(device_ref) if device_ref else None
        self.ui = ui
        self.participant = participant
        self.clock = clock
        self.factory = factory
        self.virtual = virtual
        self.progress = progress
        self._clock0 = clock.now()
        self._offset = 0.0
        self._seed = 0
        self._servo: ServoProcess | None = None  # the session's servo process, started by its first hardware trial

    # -- time --------------------------------------------------------------------------------------
    def now(self) -> float:
        """Session time in seconds: continues from the last recorded time after a resume."""
        return self._offset + (self.clock.now() - self._clock0)

    @property
    def plan(self) -> SessionPlan:
        return self.rec.state().plan

    # -- the loop ------------------------------------------------------------------------------------
    def run(self) -> SessionResult:
        """Run every step not yet done; returns when the session is complete.

        Raises :class:`SessionInterrupted` on Ctrl-C and :class:`SessionError` on a device fault, both
        after recording what happened: the session can then be resumed.
        """
        state = self.rec.state()
        if state.status == "completed":
            raise SessionError(
                f"session {state.session_id} of participant {state.participant} is already complete; "
                "nothing to run (see `studyctl status`, or `studyctl export DIR` for its data)"
            )
        if state.status == "aborted":
            raise SessionError(
                f"session {state.session_id} of participant {state.participant} was aborted; it cannot "
                "be resumed"
            )
        self._seed = state.seed
        begin_session = getattr(self.participant, "begin_session", None)
        if callable(begin_session):  # per-person traits from the session seed: the same after a resume
            begin_session(person_rng(self._seed))
        recall = getattr(self.participant, "recall", None)
        if state.memory is not None and callable(recall):  # what it had learnt by its last finished trial
            recall(state.memory)
        self._offset = state.last_t
        self._clock0 = self.clock.now()
        resuming = bool(state.started)
        if resuming:
            self._announce_resume(state)
        self.rec.set_status("running")
        refresh_checkpoint = resuming and state.plan.checkpoint == "condition"
        self._servo = ServoProcess()
        try:
            while True:
                state = self.rec.state()
                step = next((s for s in state.plan.steps if s.position not in state.completed), None)
                if step is None:
                    break
                if refresh_checkpoint:
                    self._refresh_condition(state, step)
                    refresh_checkpoint = False
                self._run_step(step)
                if self.progress is not None:
                    state = self.rec.state()
                    self.progress(len(state.completed), len(state.plan.steps), step)
        except (UsageError, InvalidAnswer) as exc:
            # A scripted answer (or other input) the session cannot use: what was done is saved; leave the
            # session resumable rather than "running" with nobody at it, and say how to continue.
            self.rec.set_status("interrupted", f"stopped by bad input: {exc}")
            sid = self.rec.state().session_id
            raise type(exc)(f"{exc}; session {sid} is saved and interrupted: fix that and continue with "
                            f"`studyctl resume {sid}` (with --input FILE for scripted answers)") from None
        except KeyboardInterrupt:
            self.rec.set_status("interrupted", "stopped by Ctrl-C")
            sid = self.rec.state().session_id
            raise SessionInterrupted(
                f"session {sid} stopped by Ctrl-C; everything done so far is saved. "
                f"Continue with `studyctl resume {sid}`"
            ) from None
        finally:
            self._servo.close()  # one servo process served every hardware trial of this run
        self.rec.event("session_end", {}, t=self.now())
        self.rec.set_status("completed")
        return self.result()

    def result(self) -> SessionResult:
        state = self.rec.state()
        statuses = [t.status for t in state.trials]
        return SessionResult(
            session_id=state.session_id,
            participant=state.participant,
            status=state.status,
            steps_done=len(state.completed),
            steps_total=len(state.plan.steps),
            trials_completed=statuses.count("completed"),
            trials_aborted=statuses.count("aborted"),
            trials_invalid=statuses.count("invalid"),
            answers=len(state.answers),
            resumes=state.resumes,
        )

    def _announce_resume(self, state: SessionState) -> None:
        pending = [s for s in state.plan.steps if s.position not in state.completed]
        interrupted = [t for t in state.trials if t.status == "running"]
        detail = {
            "session_id": state.session_id,
            "participant": state.participant,
            "previous_status": state.status,
            "steps_done": len(state.completed),
            "resume_at": pending[0].position if pending else None,
            "resume_step": pending[0].label() if pending else None,
            "interrupted_trials": [t.trial_id for t in interrupted],
            "policy": state.plan.interrupted_trial,
            "checkpoint": state.plan.checkpoint,
        }
        self.rec.audit("session_resumed", detail)
        self.rec.event("session_resumed", detail, t=self.now())
        where = pending[0].label() if pending else "the end"
        self.ui.message(f"Resuming session {state.session_id} at {where} ({len(state.completed)} steps already done)")

    def _refresh_condition(self, state: SessionState, step: Step) -> None:
        """Checkpoint ``condition``: before continuing, repeat the condition's familiarisation."""
        steps = list(state.plan.steps)
        idx = steps.index(step)
        for prev in reversed(steps[:idx]):
            if prev.kind == "familiarisation" and prev.condition == step.condition and step.condition:
                self.rec.event("checkpoint_refresh", {"familiarisation": prev.position}, t=self.now(),
                               position=step.position)
                self._familiarise(prev)
                return

    def _run_step(self, step: Step) -> None:
        handler = {
            "instructions": self._instructions,
            "familiarisation": self._familiarisation,
            "trial": self._trial,
            "break": self._break,
            "questionnaire": self._questionnaire,
            "end": self._end,
        }[step.kind]
        handler(step)

    # -- simple steps ----------------------------------------------------------------------------------
    def _instructions(self, step: Step) -> None:
        self.rec.step_started(step.position, self.now())
        self.ui.instructions(step, str(step.data.get("text", "")))
        self.rec.step_completed(step.position, self.now())

    def _end(self, step: Step) -> None:
        self.rec.step_started(step.position, self.now())
        self.ui.instructions(step, str(step.data.get("text", "The session is complete. Thank you!")))
        self.rec.step_completed(step.position, self.now())

    def _break(self, step: Step) -> None:
        self.rec.step_started(step.position, self.now())
        res = self.ui.timer("Break", float(step.duration_s or 0.0), self.clock, can_end_early=False, purpose="break")
        self.rec.step_completed(step.position, self.now(), {"elapsed_s": res.elapsed_s, "paused_s": res.paused_s})

    def _familiarisation(self, step: Step) -> None:
        self.rec.step_started(step.position, self.now())
        summary = self._familiarise(step)
        self.rec.step_completed(step.position, self.now(), summary)

    def _familiarise(self, step: Step) -> dict[str, Any]:
        can_end = bool(step.data.get("can_end_early", True))
        title = f"Familiarisation: {self._condition_label(step.condition)}"
        if step.data.get("instructions"):
            self.ui.instructions(step, str(step.data["instructions"]))
        if self._can_practise(step):
            return self._practise(step, can_end)
        res = self.ui.timer(title, float(step.duration_s or 0.0), self.clock, can_end_early=can_end,
                            purpose="familiarisation")
        return {"elapsed_s": res.elapsed_s, "ended_early": res.ended_early, "paused_s": res.paused_s}

    def _can_practise(self, step: Step) -> bool:
        """A person practises with the condition's feedback running (device and controller live)."""
        cond = self.plan.conditions.get(step.condition) if step.condition else None
        return (not self.virtual and self.ui.interactive and cond is not None and not cond.manual
                and bool(getattr(self.participant, "practises", False)) and bool(step.duration_s))

    def _practice_placement(self, step: Step) -> dict[str, Any]:
        """The example phantom: the items of the condition's trials at sites 1, 2, … (shown to the
        participant, never a trial's hidden placement)."""
        trial = next((s for s in self.plan.steps if s.kind == "trial" and s.condition == step.condition), None)
        sites = dict((trial.data.get("placement") or {}).get("sites") or {}) if trial is not None else {}
        example = {item: i for i, item in enumerate(sorted(sites), start=1)}
        return {"sites": example, "orientation_deg": 0.0 if example else None}

    def _practise(self, step: Step, can_end: bool) -> dict[str, Any]:
        cond = self.plan.conditions[step.condition]
        rate = self._rate(cond)
        placement = self._practice_placement(step)
        practice_step = replace(step, data={**dict(step.data), "placement": placement})
        info = TrialInfo(
            condition=cond.id, time_limit_s=float(step.duration_s), rate_hz=rate, visual=cond.visual,
            public={"practice": True, "example_sites": placement["sites"], "report": asdict(self.plan.report),
                    "requests": ["finish"] if can_end else []},
        )
        streams = trial_streams(self._seed, step.position)
        clock = self._child_clock()
        def should_stop() -> str | None:
            self.ui.trial_tick(clock.now() - t0)
            control = self.ui.poll_control()
            if control is not None and control.kind in ("abort", "pause"):
                return "abort"
            return None

        watch = getattr(self.ui, "trial_event", None)  # a UI that shows the loop's events live (coordinator page)

        def on_event(t: float, kind: str, payload: Mapping[str, Any]) -> None:
            self.rec.event(f"practice_{kind}", payload, t=t, position=step.position, commit=kind == "device_fault")
            if watch is not None:
                watch(t, kind, payload)

        self.ui.trial_begin(practice_step, info.time_limit_s)
        t0 = clock.now()
        try:
            outcome = self._execute(practice_step, cond, info, streams, None, should_stop, on_event, clock,
                                    samples=False)
        except DeviceError as exc:
            self.rec.set_status("interrupted", f"device fault in practice: {exc}")
            sid = self.rec.state().session_id
            raise SessionError(f"device fault during familiarisation: {exc}. The device is in its safe state; fix it, "
                               f"then `studyctl resume {sid}`") from None
        finally:
            if clock is not self.clock:
                self.clock.sleep_until(self.clock.now() + (clock.now() - t0))
        summary = {"elapsed_s": outcome.duration_s, "ended_early": outcome.ended_by == "finish", "paused_s": 0.0,
                   "practice": True, "ended_by": outcome.ended_by, "ticks": outcome.ticks}
        self.ui.trial_end(practice_step, {**summary, "duration_s": outcome.duration_s, "status": "practice"})
        return summary

    def _condition_label(self, condition: str | None) -> str:
        if condition is None:
            return ""
        spec = self.plan.conditions.get(condition)
        return (spec.label or spec.id) if spec else condition

    # -- questionnaires ------------------------------------------------------------------------------
    def _questionnaire(self, step: Step) -> None:
        state = self.rec.state()
        plan = state.plan
        instrument = plan.instruments[step.data["instrument"]]
        self.rec.step_started(step.position, self.now())
        context = {
            "position": step.position,
            "when": step.data.get("when"),
            "condition": step.condition,
            "block": step.block,
            "trials": [
                dict(t.outcome) for t in state.trials
                if t.status == "completed" and (step.condition is None or t.condition == step.condition)
            ],
            # every completed trial in plan order: a participant may base answers on it instead of memory,
            # so a resumed session answers exactly as an uninterrupted one
            "history": [
                {"condition": t.condition, **self._told(plan, t.condition), **dict(t.outcome)}
                for t in self._in_plan_order(state) if t.status == "completed"
            ],
        }
        for number, item in enumerate(instrument.items, start=1):
            if (step.position, item.id) in state.answers:
                continue  # answered before an interruption: kept, never asked twice
            code, rt = self.ui.ask_item(instrument, item, number, context)
            if code not in item.codes():  # a plugin's answer gets the same check as a typed one
                raise SessionError(
                    f"participant answered {code!r} to item {item.id!r} of {instrument.id!r}; "
                    f"allowed codes: {list(item.codes())}"
                )
            self.rec.answer(step.position, instrument.id, instrument.version, item.id, code, rt)
        self.rec.step_completed(step.position, self.now(), {"instrument": instrument.id,
                                                            "version": instrument.version})

    @staticmethod
    def _told(plan: SessionPlan, condition: str | None) -> dict[str, Any]:
        """What the participant was told about a trial's condition (its name, the view it had, whether it was
        manual): known to a person, and needed to judge one scenario against another from the record."""
        spec = plan.conditions.get(condition) if condition else None
        if spec is None:
            return {}
        return {"label": spec.label or spec.id, "visual": spec.visual, "manual": spec.manual}

    @staticmethod
    def _in_plan_order(state: SessionState) -> list:
        order = {s.position: i for i, s in enumerate(state.plan.steps)}
        return sorted(state.trials, key=lambda t: (order.get(t.position, 0), t.attempt))

    # -- trials --------------------------------------------------------------------------------------------
    def _trial(self, step: Step) -> None:
        state = self.rec.state()
        attempts = state.attempts(step.position)
        for a in attempts:
            if a.status == "running":  # the process died in this attempt
                self.rec.mark_trial(a.trial_id, "aborted", INTERRUPTED_REASON)
        attempts = self.rec.state().attempts(step.position)
        if attempts and self.plan.interrupted_trial == "invalidate_and_append":
            self._replace(step, attempts)
            return
        self._attempt(step, len(attempts) + 1, attempts[-1].trial_id if attempts else None)

    def _replace(self, step: Step, attempts: list) -> None:
        plan = self.plan
        for a in attempts:
            if a.status != "invalid":
                self.rec.mark_trial(a.trial_id, "invalid", f"replaced per protocol policy ({a.reason})")
        existing = [s for s in plan.steps if s.replaces == step.position]
        if existing:  # the amendment was committed before a crash: do not append twice
            new = existing[0]
        else:
            new_plan, new = plan.with_replacement(step.position)
            self.rec.amend_plan(new_plan, f"replacement {new.position} for interrupted trial step {step.position}")
        self.rec.audit("trial_replaced", {"step": step.position, "replacement": new.position,
                                          "trials": [a.trial_id for a in attempts]})
        self.rec.step_completed(step.position, self.now(), {"status": "invalid", "replaced_by": new.position})

    def _time_limit(self, step: Step) -> float:
        if step.duration_s:
            return float(step.duration_s)
        return float("inf") if (self.ui.interactive and not self.virtual) else UNATTENDED_TRIAL_CAP_S

    def _trial_info(self, step: Step, cond: ConditionSpec, rate_hz: float) -> TrialInfo:
        plan = self.plan
        return TrialInfo(
            condition=cond.id,
            time_limit_s=self._time_limit(step),
            rate_hz=rate_hz,
            visual=cond.visual,
            public={
                "trial_index": step.trial_index,
                "block": step.block,
                "repetition": step.repetition,
                "report": asdict(plan.report),
                "requests": list(plan.requests),
                **dict(step.data.get("public", {})),
            },
        )

    def _attempt(self, step: Step, attempt: int, replaces: int | None) -> None:
        plan = self.plan
        cond = plan.conditions[step.condition]
        rate = self._rate(cond)
        info = self._trial_info(step, cond, rate)
        streams = trial_streams(self._seed, step.position)
        tid = self.rec.trial_started(  # also records entering the step, in the same commit
            step.position, attempt, self.now(),
            {"condition": cond.id, "attempt": attempt, "replaces_trial_id": replaces, "time_limit_s":
             step.duration_s, "rate_hz": rate, "visual": cond.visual},
        )
        flag: dict[str, Any] = {"invalid": None, "stop": None}
        self.ui.trial_begin(step, info.time_limit_s)
        # A simulated trial runs on its own clock from 0, so trial times are exact multiples of the period
        # whatever the session time: a repeated or resumed trial sees bit-identical times.
        trial_clock: Clock = self._child_clock()
        t_start = trial_clock.now()

        def poll() -> str | None:
            self.ui.trial_tick(trial_clock.now() - t_start)
            control = self.ui.poll_control()
            if control is None:
                return None
            return self._control(control, tid, trial_clock.now() - t_start, flag)

        # nothing to poll for a virtual participant's prompts: keep the loop lean
        should_stop = poll if getattr(self.ui, "controls", True) else None

        watch = getattr(self.ui, "trial_event", None)  # a UI that shows the loop's events live (coordinator page)

        def on_event(t: float, kind: str, payload: Mapping[str, Any]) -> None:
            # Scans and reports are a participant's answers: committed at once. The rest rides along.
            self.rec.event(kind, payload, t=t, trial_id=tid, commit=kind in ("scan", "report"))
            if watch is not None:
                watch(t, kind, payload)

        try:
            if cond.manual and not self.virtual:
                outcome = self._manual(step, info, streams, trial_clock, tid)
            elif cond.manual:
                outcome = self._simulated_manual(step, cond, info, streams, tid, should_stop, trial_clock)
            else:
                outcome = self._execute(step, cond, info, streams, tid, should_stop, on_event, trial_clock)
        except KeyboardInterrupt:
            self._abort_attempt(tid, step, "stopped by Ctrl-C", t_start, trial_clock)
            raise
        except DeviceError as exc:
            self._abort_attempt(tid, step, f"device fault: {exc}", t_start, trial_clock)
            self.rec.event("device_fault", {"error": str(exc)}, t=self.now(), trial_id=tid)
            self.rec.set_status("interrupted", f"device fault: {exc}")
            sid = self.rec.state().session_id
            raise SessionError(
                f"device fault in {step.label()}: {exc}. The device was put in its safe state, the trial is "
                f"recorded as aborted and nothing else is lost; fix the device, then `studyctl resume {sid}`"
            ) from None
        except StudyctlError as exc:
            self._abort_attempt(tid, step, f"{type(exc).__name__}: {exc}", t_start, trial_clock)
            self.rec.set_status("interrupted", str(exc))
            raise
        except Exception as exc:  # a plugin bug: record it, keep the traceback for the developer
            self._abort_attempt(tid, step, f"plugin error: {type(exc).__name__}: {exc}", t_start, trial_clock)
            self.rec.set_status("interrupted", f"plugin error: {type(exc).__name__}")
            raise
        finally:
            if trial_clock is not self.clock:  # the session clock moves on by the trial's duration
                self.clock.sleep_until(self.clock.now() + (trial_clock.now() - t_start))
        self._finish_attempt(step, tid, attempt, outcome, flag, rate)

    def _child_clock(self) -> Clock:
        if not self.clock.simulated:
            return self.clock
        child = getattr(self.clock, "child", None)
        return child() if callable(child) else SimulatedClock(0.0)

    def _rate(self, cond: ConditionSpec) -> float:
        return condition_rate(cond, self.factory)

    def _control(self, control: Control, tid: int, t: float, flag: dict[str, Any]) -> str | None:
        if control.kind == "note":  # typed during the trial: kept, the trial goes on
            self.rec.event("coordinator_note", {"text": control.reason}, t=t, trial_id=tid)
            self.rec.audit("note", {"text": control.reason[:4000], "trial_id": tid,
                                    "session_id": self.rec.session_id, "during_trial": True})
            return None
        if control.kind == "invalid":
            flag["invalid"] = control.reason or "marked invalid by the coordinator"
            self.rec.event("coordinator_mark_invalid", {"reason": flag["invalid"]}, t=t, trial_id=tid)
            self.rec.audit("trial_marked_invalid", {"trial_id": tid, "reason": flag["invalid"]})
            return None
        if control.kind in ("abort", "pause"):
            flag["stop"] = control
            self.rec.event(f"coordinator_{control.kind}", {"reason": control.reason}, t=t, trial_id=tid)
            return control.kind
        return None

    def _abort_attempt(self, tid: int, step: Step, reason: str, t_start: float, trial_clock: Clock) -> None:
        duration = trial_clock.now() - t_start
        self.rec.trial_finished(
            tid, "aborted", {"ended_by": "fault", "duration_s": duration, "step": step.position}, [],
            position=step.position, t=self.now(), reason=reason, complete_step=False,
        )

    def _finish_attempt(
        self, step: Step, tid: int, attempt: int, outcome: TrialOutcome, flag: dict[str, Any], rate: float
    ) -> None:
        plan = self.plan
        reports = []
        rejected = 0
        for rep in outcome.reports:
            payload = {k: v for k, v in rep.items() if k != "t"}
            try:
                clean = plan.report.validate_payload(payload)
            except InvalidAnswer as exc:
                rejected += 1
                self.rec.event("report_rejected", {"payload": payload, "reason": str(exc)}, t=rep.get("t"),
                               trial_id=tid)
                continue
            reports.append({"t": rep.get("t"), **clean})
        summary = {
            "ended_by": outcome.ended_by,
            "timed_out": outcome.ended_by == "time_limit",
            "duration_s": outcome.duration_s,
            "ticks": outcome.ticks,
            "scans": outcome.scans,
            "reports": len(reports),
            "rejected_reports": rejected,
            "attempt": attempt,
            "step": step.position,
            "rate_hz": rate,
        }
        self._remember(tid, outcome.duration_s)  # committed with the trial's record below, whatever its status
        if outcome.ended_by == "fault":
            error = next((e.get("error") or e.get("rule") for e in reversed(outcome.events)
                          if e.get("kind") == "device_fault"), "the safety layer held the device in its safe state")
            reason = f"device fault: {error}"
            self.rec.trial_finished(tid, "aborted", summary, reports, position=step.position, t=self.now(),
                                    reason=reason, complete_step=False)
            self.rec.set_status("interrupted", reason)
            sid = self.rec.state().session_id
            self.ui.trial_end(step, {**summary, "status": "aborted", "reason": reason})
            raise SessionError(
                f"{reason} in {step.label()}. The device was put in its safe state, the trial is recorded as "
                f"aborted and nothing else is lost; fix the device, then `studyctl resume {sid}`"
            )
        stop: Control | None = flag["stop"]
        if stop is not None:
            reason = f"{'paused' if stop.kind == 'pause' else 'aborted'} by the coordinator: {stop.reason}"
            self.rec.trial_finished(tid, "aborted", summary, reports, position=step.position, t=self.now(),
                                    reason=reason, complete_step=False)
            self.rec.audit("trial_aborted", {"trial_id": tid, "reason": reason})
            self.ui.trial_end(step, {**summary, "status": "aborted", "reason": reason})
            if stop.kind == "pause":
                self.rec.set_status("paused", stop.reason)
                self.ui.wait_unpause()
                self.rec.set_status("running", "continued after pause")
            return
        status = "invalid" if flag["invalid"] else "completed"
        self.rec.trial_finished(tid, status, summary, reports, position=step.position, t=self.now(),
                                reason=flag["invalid"] or "")
        self.ui.trial_end(step, {**summary, "status": status})

    def _remember(self, tid: int, t: float) -> None:
        """Store the participant's memory at the end (trial time ``t``) of the trial it ends, committed with the
        trial's record."""
        memory = getattr(self.participant, "memory", None)
        mem = memory() if callable(memory) else None
        if mem:
            self.rec.event(MEMORY_EVENT, {"memory": dict(mem)}, t=t, trial_id=tid, commit=False)

    def _manual(self, step: Step, info: TrialInfo, streams: TrialStreams, clock: Clock, tid: int) -> TrialOutcome:
        if self.plan.scene:  # the phantom as placed for this trial: what its outcome is scored against
            placement = step.data.get("placement") or {}
            scene = build_scene(self.factory, self.plan.scene, self.plan.scene_spec, placement, frozenset(),
                                streams.scene)
            self._record_truth(scene, tid)
        res = self.ui.manual_outcome(step, self.plan.report, clock)
        return self._manual_outcome(res, info, tid, "coordinator")

    def _record_truth(self, scene: Any, tid: int) -> None:
        """Store the hidden truth the metrics score this trial against (tumour sites, nodule centres) with the
        trial, so that analysis reads it instead of rebuilding the scene with later code."""
        self.rec.event("scene_truth", scene.truth(), t=0.0, trial_id=tid, commit=False)

    def _manual_outcome(
        self, res: ManualOutcome, info: TrialInfo, tid: int, entered_by: str, ended_by: str | None = None,
        events: list | None = None,
    ) -> TrialOutcome:
        """Record a manual trial's outcome: one ``manual_outcome`` event; the reports at the stopwatch time."""
        self.rec.event("manual_outcome", {"entered_by": entered_by, "duration_s": res.duration_s,
                                          "reports": len(res.reports), "note": res.note},
                       t=res.duration_s, trial_id=tid, durable=True)
        reports = [{"t": res.duration_s, **r} for r in res.reports]
        limit = info.time_limit_s
        ended = ended_by or ("time_limit" if res.duration_s >= limit else "finish")
        return TrialOutcome(ended, min(res.duration_s, limit), 0, 0, reports, list(events or []))

    def _simulated_manual(
        self, step, cond, info, streams: TrialStreams, tid, should_stop, trial_clock: Clock
    ) -> TrialOutcome:
        """A virtual participant in a manual condition palpates the trial's scene with the simulated bare finger
        (no controller, device :data:`MANUAL_TOUCH_DEVICE`) and its reports become the trial's outcome, recorded
        exactly as a coordinator's entry for a person (no samples, no per-report events: nothing is instrumented
        in a manual trial); the ``manual_outcome`` event says it was simulated."""

        def on_event(t: float, kind: str, payload: Mapping[str, Any]) -> None:
            if kind == "device_fault":  # the rest is loop bookkeeping a person's manual trial does not have
                self.rec.event(kind, payload, t=t, trial_id=tid)

        run = self._execute(step, cond, info, streams, tid, should_stop, on_event, trial_clock)
        note = (f"simulated: virtual participant {getattr(self.participant, 'name', '?')} palpated the phantom "
                f"with a bare finger (device {MANUAL_TOUCH_DEVICE}, {run.ticks} ticks at {info.rate_hz:g} Hz)")
        res = ManualOutcome(run.duration_s, tuple({k: v for k, v in r.items() if k != "t"} for r in run.reports),
                            note)
        ended = run.ended_by if run.ended_by not in ("finish", "time_limit") else None
        return self._manual_outcome(res, info, tid, "simulated", ended, run.events)

    def _device_ref(self) -> Mapping[str, Any]:
        plan = self.plan
        if self.device_override is not None and (not self.virtual or self.device_override.get("world")):
            return self.device_override
        ref = plan.simulated_device if self.virtual else (plan.hardware_device or plan.simulated_device)
        if not ref:
            raise SessionError(f"the plan of study {plan.study!r} names no device to run trials on")
        return ref

    def _uses_servo(self, device_name: str) -> bool:
        """Hardware trials run in the servo process (the loop's own process); simulated ones in this one."""
        if self.servo is not None:
            return self.servo and not self.virtual_device(device_name)
        return isinstance(self.factory, EntryPointFactory) and not self.virtual_device(device_name)

    def virtual_device(self, name: str) -> bool:
        return bool(getattr(self.factory.load("device", name), "simulated", True))

    def _execute(
        self, step, cond, info, streams: TrialStreams, tid, should_stop, on_event, trial_clock: Clock,
        *, samples: bool = True,
    ) -> TrialOutcome:
        plan = self.plan
        controller_name = None if cond.manual else cond.controller
        needs = controller_needs(self.factory, controller_name, cond.params, cond.visual)
        ref = {"plugin": MANUAL_TOUCH_DEVICE} if cond.manual else self._device_ref()
        servo = self._uses_servo(ref["plugin"])
        # the servo child builds its own scene and device from the same streams: copies taken before use here
        child_rngs = (copy.deepcopy(streams.scene), copy.deepcopy(streams.device)) if servo else None
        scene = None
        placement = step.data.get("placement") or {}
        if plan.scene:
            scene = build_scene(self.factory, plan.scene, plan.scene_spec, placement, needs, streams.scene)
            if tid is not None:
                self._record_truth(scene, tid)
        if scene is not None and callable(getattr(scene, "public", None)):
            # what a participant may know about the scene (grid, visible surface), never its hidden truth
            info = replace(info, public={**dict(scene.public() or {}), **dict(info.public)})
        # a manual trial has no instrument to log; practice is not data
        sink = None if cond.manual or not samples else self.rec.samples(tid, [])
        if servo:
            spec = ServoSpec(
                info=info, device=ref["plugin"], device_params=dict(ref.get("params", {})),
                controller=controller_name, controller_params=dict(cond.params) if controller_name else {},
                scene=plan.scene, scene_spec=dict(plan.scene_spec or {}), scene_placement=dict(placement),
                scene_needs=needs, scene_rng=child_rngs[0], device_rng=child_rngs[1],
                participant_rng=copy.deepcopy(streams.participant),
                **self._child_person(ref),
            )
            try:
                return self._execute_in_servo(spec, scene, info, streams, should_stop, on_event, sink, trial_clock)
            finally:
                if sink is not None:
                    sink.close()
        controller = build_controller(self.factory, controller_name, cond.params, scene) if controller_name else None
        device = build_device(self.factory, ref["plugin"], ref.get("params", {}), scene, streams.device)
        if ref.get("world"):  # a virtual participant's hand on emulated hardware
            from studyctl.devices.world import embody  # noqa: PLC0415

            device = embody(device, ref["world"], scene)
        # hardware keeps real time whatever the session's clock (a scripted rehearsal's is simulated): on a
        # simulated clock its sensor would look stale after a few ticks of computation
        loop_clock = RealClock() if trial_clock.simulated and not self.virtual_device(ref["plugin"]) else trial_clock
        try:
            device.open()
            identity = getattr(device, "identity", None)
            if callable(identity):  # as the servo process does: what the device says it is, for the record
                on_event(0.0, "device_identity", dict(identity()))
            outcome = run_trial(
                info=info,
                controller=controller,
                device=device,
                participant=self.participant,
                clock=loop_clock,
                rng=streams.participant,
                on_event=on_event,
                on_sample=sink.write if sink is not None else None,
                view=scene.view if scene is not None else None,
                should_stop=should_stop,
            )
            if loop_clock is not trial_clock:
                trial_clock.sleep_until(trial_clock.now() + outcome.duration_s)
            return outcome
        finally:
            try:
                device.close()
            except Exception as exc:  # closing a disconnected device may fail; the fault is already raised
                self.rec.event("device_close_failed", {"error": f"{type(exc).__name__}: {exc}"}, trial_id=tid)
            if sink is not None:
                sink.close()

    def _child_person(self, ref: Mapping[str, Any]) -> dict[str, Any]:
        """ServoSpec fields that put the session's virtual participant in the servo process, acting on emulated
        hardware through the emulator's world (``run --rehearse --virtual``); none otherwise."""
        if not (self.virtual and ref.get("world")):
            return {}
        if self.virtual_ref is None:
            raise SessionError("a virtual participant on emulated hardware needs its plugin name to be rebuilt in "
                               "the servo process (SessionRunner(virtual_ref=…))")
        memory = getattr(self.participant, "memory", None)
        return {"participant": self.virtual_ref["plugin"], "participant_params": dict(self.virtual_ref["params"]),
                "session_seed": self._seed, "participant_memory": dict(memory() or {}) if callable(memory) else None,
                "world": dict(ref["world"])}

    def _execute_in_servo(
        self, spec: ServoSpec, scene: Any, info: TrialInfo, streams: TrialStreams, should_stop, on_event, sink,
        trial_clock: Clock,
    ) -> TrialOutcome:
        """Run the trial's loop in the servo process; here the participant's requests are polled (a person at the
        terminal or view, or a script), scan and real-time views are rendered from the poses the loop reports,
        and samples and events are stored. A simulated trial clock (scripted rehearsal) follows the loop's time."""
        participant = self.participant
        in_child = spec.participant is not None  # a virtual participant acts in the servo process itself
        if not in_child:
            participant.begin_trial(info, copy.deepcopy(streams.participant))
        t_start = trial_clock.now()
        latest: dict[str, Any] = {"t": 0.0, "sample": {}, "scan": None}
        realtime_view = info.visual == "realtime" and scene is not None
        last_view = [-1.0]

        def follow(t: float) -> None:
            latest["t"] = t
            if trial_clock.simulated and t_start + t > trial_clock.now():
                trial_clock.sleep_until(t_start + t)

        def on_sample(t: float, values: Mapping[str, float]) -> None:
            follow(t)
            latest["sample"] = values
            if sink is not None:
                sink.write(t, values)

        def on_child_event(t: float, kind: str, payload: Mapping[str, Any]) -> None:
            if kind == "scan" and scene is not None:
                latest["scan"] = scene.view(payload.get("pose") or {})
            on_event(t, kind, payload)

        def requests() -> list:
            percept: dict[str, Any] = {}
            if latest["scan"] is not None:
                percept["scan"], latest["scan"] = latest["scan"], None
            if realtime_view and latest["t"] - last_view[0] >= 1 / 30:  # the screen's rate, not the loop's
                last_view[0] = latest["t"]
                percept["view"] = scene.view(latest["sample"])
            return list(participant.act(latest["t"], percept).requests)

        servo = self._servo or ServoProcess()  # outside run() (a test's single trial): a process of its own
        try:
            result = servo.run_trial(spec, on_event=on_child_event, on_sample=on_sample,
                                     requests=None if in_child else requests, should_stop=should_stop)
        finally:
            if servo is not self._servo:
                servo.close()
        follow(result.duration_s)
        recall = getattr(participant, "recall", None)
        if in_child and result.memory is not None and callable(recall):  # what it learnt in the child's trial
            recall(result.memory)
        return TrialOutcome(result.ended_by, result.duration_s, result.ticks, result.scans, result.reports,
                            result.events)
