"""The trial steps of a session: record an attempt, run it, score its reports and finish it (or abort it).

Part of :class:`~studyctl.engine.session.SessionRunner` (a mixin: the runner's recorder, prompts, clock, plan and
trial executor are used as its own); split off because a trial attempt's bookkeeping is the largest part of the
state machine. The rules it keeps (record then act, one row per attempt, repeat or invalidate-and-append) are
stated in :mod:`studyctl.engine.session`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import asdict
from typing import TYPE_CHECKING, Any

from studyctl.engine.clock import Clock
from studyctl.engine.plan import ConditionSpec, Step
from studyctl.engine.recorder import MEMORY_EVENT
from studyctl.engine.seeding import trial_streams
from studyctl.engine.trial_loop import TrialOutcome
from studyctl.engine.ui import Control
from studyctl.errors import DeviceError, InvalidAnswer, SessionError, StudyctlError
from studyctl.plugins.interfaces import TrialInfo

if TYPE_CHECKING:
    from studyctl.engine.plan import SessionPlan
    from studyctl.engine.recorder import Recorder
    from studyctl.engine.trial_exec import TrialExecutor
    from studyctl.engine.ui import SessionUI
    from studyctl.plugins.interfaces import Participant

# A trial without a time limit (completion time is the measure) still needs an end when nobody can stop it:
# virtual and scripted runs stop such a trial here and record it as timed out.
UNATTENDED_TRIAL_CAP_S = 1800.0
INTERRUPTED_REASON = "interrupted: the session stopped during this trial (crash, kill or power loss)"


class TrialSteps:
    """Trial steps of :class:`~studyctl.engine.session.SessionRunner` (which provides the attributes below)."""

    rec: Recorder
    ui: SessionUI
    participant: Participant
    clock: Clock
    virtual: bool
    trials: TrialExecutor
    _seed: int
    plan: SessionPlan

    now: Callable[[], float]  # the runner's session time
    _child_clock: Callable[[], Clock]  # a simulated trial's own clock
    _rate: Callable[[ConditionSpec], float]  # a condition's loop rate

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
                outcome = self.trials.manual(step, info, streams, trial_clock, tid)
            elif cond.manual:
                outcome = self.trials.simulated_manual(step, cond, info, streams, tid, should_stop, trial_clock)
            else:
                outcome = self.trials.execute(step, cond, info, streams, tid, should_stop, on_event, trial_clock)
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
        # committed with the trial's record below, whatever its status
        self._remember(trial_id=tid, t=outcome.duration_s)
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

    def _remember(self, **where: Any) -> None:
        """Store the participant's memory where ``where`` places the event (a trial's end: ``trial_id`` and trial
        time ``t``; a practice: its ``position``), committed with the record that follows."""
        memory = getattr(self.participant, "memory", None)
        mem = memory() if callable(memory) else None
        if mem:
            self.rec.event(MEMORY_EVENT, {"memory": dict(mem)}, commit=False, **where)
