"""Running one trial's loop: build its scene, controller and device, and run it here or in the servo process.

The session runner (:mod:`studyctl.engine.session`) decides *which* trial runs and records its attempt; this
module makes the trial happen: a simulated or emulated device in this process, hardware in the servo process
(:mod:`studyctl.engine.servo`), a manual condition as the coordinator's entry or, for a virtual participant, the
simulated bare finger on the same scene. Samples go to the recorder's sink; events to the caller's ``on_event``.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from studyctl.engine.clock import Clock, RealClock
from studyctl.engine.factory import (
    MANUAL_TOUCH_DEVICE,
    EntryPointFactory,
    PluginFactory,
    build_controller,
    build_device,
    build_scene,
    controller_needs,
)
from studyctl.engine.plan import SessionPlan, Step
from studyctl.engine.recorder import Recorder
from studyctl.engine.seeding import TrialStreams
from studyctl.engine.servo import ServoProcess, ServoSpec
from studyctl.engine.trial_loop import TrialOutcome, run_trial
from studyctl.engine.ui import ManualOutcome, SessionUI
from studyctl.errors import SessionError
from studyctl.plugins.interfaces import Participant, TrialInfo


class TrialExecutor:
    """Builds and runs trials for one :class:`~studyctl.engine.session.SessionRunner` (see its parameters:
    ``virtual``, ``servo``, ``device_ref`` and ``virtual_ref`` mean the same here). ``seed`` is the session's,
    set by the runner when it starts (a virtual participant rebuilt in the servo process needs it)."""

    def __init__(
        self,
        recorder: Recorder,
        *,
        ui: SessionUI,
        participant: Participant,
        factory: PluginFactory,
        virtual: bool,
        servo: bool | None = None,
        device_ref: Mapping[str, Any] | None = None,
        virtual_ref: Mapping[str, Any] | None = None,
    ) -> None:
        self.rec = recorder
        self.ui = ui
        self.participant = participant
        self.factory = factory
        self.virtual = virtual
        self.servo = servo
        self.device_override = dict(device_ref) if device_ref else None
        self.virtual_ref = dict(virtual_ref) if virtual_ref else None
        self.seed = 0
        self.servo_process: ServoProcess | None = None  # the session's servo process (set by the runner's run)

    @property
    def plan(self) -> SessionPlan:
        return self.rec.state().plan

    def manual(self, step: Step, info: TrialInfo, streams: TrialStreams, clock: Clock, tid: int) -> TrialOutcome:
        if self.plan.scene:  # the phantom as placed for this trial: what its outcome is scored against
            placement = step.data.get("placement") or {}
            scene = build_scene(self.factory, self.plan.scene, self.plan.scene_spec, placement, frozenset(),
                                streams.scene)
            self.record_truth(scene, tid)
        res = self.ui.manual_outcome(step, self.plan.report, clock)
        return self._manual_outcome(res, info, tid, "coordinator")

    def record_truth(self, scene: Any, tid: int) -> None:
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

    def simulated_manual(
        self, step, cond, info, streams: TrialStreams, tid, should_stop, trial_clock: Clock
    ) -> TrialOutcome:
        """A virtual participant in a manual condition palpates the trial's scene with the simulated bare finger
        (no controller, device :data:`MANUAL_TOUCH_DEVICE`) and its reports become the trial's outcome, recorded
        exactly as a coordinator's entry for a person (no samples, no per-report events: nothing is instrumented
        in a manual trial); the ``manual_outcome`` event says it was simulated."""

        def on_event(t: float, kind: str, payload: Mapping[str, Any]) -> None:
            if kind == "device_fault":  # the rest is loop bookkeeping a person's manual trial does not have
                self.rec.event(kind, payload, t=t, trial_id=tid)

        run = self.execute(step, cond, info, streams, tid, should_stop, on_event, trial_clock)
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

    def execute(
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
                self.record_truth(scene, tid)
        if scene is not None and callable(getattr(scene, "public", None)):
            # what a participant may know about the scene (grid, visible surface), never its hidden truth
            info = replace(info, public={**dict(scene.public() or {}), **dict(info.public)})
            if info.public.get("practice") and callable(getattr(scene, "marks", None)):
                # the example phantom has its items marked on it (seed 000: the 3 tumour sites are marked)
                info = replace(info, public={**dict(info.public), "marks": list(scene.marks())})
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
                on_sample_parts=getattr(sink, "write_parts", None),
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
                "session_seed": self.seed, "participant_memory": dict(memory() or {}) if callable(memory) else None,
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

        servo = self.servo_process or ServoProcess()  # outside run() (a test's single trial): a process of its own
        try:
            result = servo.run_trial(spec, on_event=on_child_event, on_sample=on_sample,
                                     requests=None if in_child else requests, should_stop=should_stop)
        finally:
            if servo is not self.servo_process:
                servo.close()
        follow(result.duration_s)
        recall = getattr(participant, "recall", None)
        if in_child and result.memory is not None and callable(recall):  # what it learnt in the child's trial
            recall(result.memory)
        return TrialOutcome(result.ended_by, result.duration_s, result.ticks, result.scans, result.reports,
                            result.events)
