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

from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, replace
from typing import Any

import pandas as pd

from studyctl.engine.clock import Clock, SimulatedClock
from studyctl.engine.factory import PluginFactory
from studyctl.engine.plan import ConditionSpec, SessionPlan, Step
from studyctl.engine.questionnaire import questionnaire_context
from studyctl.engine.recorder import Recorder, SessionState
from studyctl.engine.seeding import person_rng, trial_streams
from studyctl.engine.servo import ServoProcess
from studyctl.engine.trial_exec import TrialExecutor
from studyctl.engine.trial_steps import TrialSteps
from studyctl.engine.ui import SessionUI
from studyctl.errors import DeviceError, InvalidAnswer, SessionError, SessionInterrupted, UsageError
from studyctl.plugins.interfaces import Participant, TrialInfo

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


class SessionRunner(TrialSteps):
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
        self.ui = ui
        self.participant = participant
        self.clock = clock
        self.virtual = virtual
        self.progress = progress
        self._clock0 = clock.now()
        self._offset = 0.0
        self._seed = 0
        self.trials = TrialExecutor(recorder, ui=ui, participant=participant, factory=factory, virtual=virtual,
                                    servo=servo, device_ref=device_ref, virtual_ref=virtual_ref)

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
        self._seed = self.trials.seed = state.seed
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
        # one servo process serves every hardware trial of this run, started by the first
        self.trials.servo_process = ServoProcess()
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
            self.trials.servo_process.close()  # one servo process served every hardware trial of this run
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
        """A person practises with the condition's feedback running (device and controller live): a person at the
        terminal, or a virtual participant that practises (it learns what the feedback tells it on the example).
        In a manual condition a person practises on the real phantom while the familiarisation timer runs; a
        virtual participant that asks for it (``practises_manual``; seed 002's transparent practice phantom)
        palpates the example with the simulated bare finger, as it palpates the condition's trials."""
        cond = self.plan.conditions.get(step.condition) if step.condition else None
        if cond is None or not step.duration_s:
            return False
        if cond.manual:
            return self.virtual and bool(getattr(self.participant, "practises_manual", False))
        return (self.virtual or self.ui.interactive) and bool(getattr(self.participant, "practises", False))

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
            outcome = self.trials.execute(practice_step, cond, info, streams, None, should_stop, on_event, clock,
                                    samples=False)
        except DeviceError as exc:
            self.rec.set_status("interrupted", f"device fault in practice: {exc}")
            sid = self.rec.state().session_id
            raise SessionError(f"device fault during familiarisation: {exc}. The device is in its safe state; fix it, "
                               f"then `studyctl resume {sid}`") from None
        finally:
            if clock is not self.clock:
                self.clock.sleep_until(self.clock.now() + (clock.now() - t0))
        # what was learnt in practice is memory too: a session resumed before the next trial ends goes on with it
        self._remember(position=step.position)
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
        context = questionnaire_context(state, step)
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

    def _child_clock(self) -> Clock:
        if not self.clock.simulated:
            return self.clock
        child = getattr(self.clock, "child", None)
        return child() if callable(child) else SimulatedClock(0.0)

    def _rate(self, cond: ConditionSpec) -> float:
        # the plugin factory has one holder, the trial executor, which builds every plugin of the session
        return condition_rate(cond, self.trials.factory)

    def virtual_device(self, name: str) -> bool:
        """True when the device plugin ``name`` is simulated (its trials run in this process)."""
        return self.trials.virtual_device(name)
