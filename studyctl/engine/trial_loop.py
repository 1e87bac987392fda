"""The per-trial feedback loop, shared by people and virtual participants.

Persistence is the caller's: samples and events leave through the ``sink`` callbacks so that the
loop stays free of I/O and the session engine decides when to commit.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from studyctl.engine.clock import Clock
from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import Controller, Device, Participant, TrialInfo
from studyctl.plugins.safety import SafetyLayer, Watchdog

# A device held in its safe state by a fault (stale sensor, disconnected board) this long ends the trial.
FAULT_ABORT_S = 1.0

# device_fault rules that come from the loop's own timing (a tick past its deadline, a stalled loop: the safety layer
# and the watchdog), not from the device: a loaded machine produces them, so checks of the device set them apart
TIMING_FAULTS = ("missed_deadline", "loop_stalled")


@dataclass
class TrialOutcome:
    """What happened in one trial, as the loop saw it."""

    ended_by: str  # "finish", "time_limit", "abort", "fault"
    duration_s: float
    ticks: int
    scans: int
    reports: list[dict[str, Any]] = field(default_factory=list)
    events: list[dict[str, Any]] = field(default_factory=list)


EventSink = Callable[[float, str, Mapping[str, Any]], None]
SampleSink = Callable[[float, Mapping[str, float]], None]


def run_trial(
    *,
    info: TrialInfo,
    controller: Controller | None,
    device: Device,
    participant: Participant,
    clock: Clock,
    rng: np.random.Generator,
    on_event: EventSink | None = None,
    on_sample: SampleSink | None = None,
    view: Callable[[Mapping[str, float]], Mapping[str, Any] | None] | None = None,
    should_stop: Callable[[], str | None] | None = None,
    on_sample_parts: Callable[[float, Mapping[str, float], Mapping[str, float], Mapping[str, float]], None]
    | None = None,
    on_start: Callable[[float], None] | None = None,
) -> TrialOutcome:
    """Run one trial to its end: the participant finishes, the time limit passes, or it is stopped.

    ``view`` renders a visual frame from the device inputs (the scene's CT slice or cursor view); it is
    called on each scan request (counted) or every tick in real-time visual conditions.
    ``should_stop`` is polled every tick and returns a reason ("abort", "pause") to end the trial.

    Optional controller extras (duck-typed, so older controllers keep working): a ``diagnostics`` dict that
    the controller updates in place each step (model state such as needle depth or tissue layer) is logged
    with every sample and passed to ``view``; an ``events`` list of ``{"kind": …, …}`` dicts (puncture,
    contact …) is drained into the event log each tick. ``view`` receives the participant's inputs
    overlaid with the device's observation (the real pose, also with hardware) and the diagnostics.
    ``on_sample_parts(t, values, written, diagnostics)``, when given instead of ``on_sample``, takes the
    sample's three parts unmerged (the same sample as ``{**values, **written, **diagnostics}``) so that a
    sink that keeps fixed channels need not build a dict every tick.
    ``on_start(start)`` is called with the clock's reading at trial time 0, as soon as it is taken (the servo
    process places the trial on the monotonic clock with it, for Lab Streaming Layer time stamps).
    """
    events: list[dict[str, Any]] = []

    def emit(t: float, kind: str, payload: Mapping[str, Any]) -> None:
        events.append({"t": t, "kind": kind, **payload})
        if on_event is not None:
            on_event(t, kind, payload)

    period = 1.0 / info.rate_hz
    safety = SafetyLayer(device.limits, period_s=period)
    watchdog: Watchdog | None = None
    if not getattr(clock, "simulated", False):
        # Real time: a thread commands the safe state if the loop stalls inside a plugin.
        def _stalled(late_s: float) -> None:
            device.write(safety.safe_command())
            safety.record(clock.now() - start, "device_fault", "loop_stalled", late_s=late_s)

        watchdog = Watchdog(safety.deadline_factor * period, _stalled)
    participant.begin_trial(info, rng)
    if controller is not None:
        set_rate = getattr(controller, "set_loop_rate", None)  # duck-typed controllers may lack it
        if set_rate is not None:
            set_rate(info.rate_hz)
        controller.reset()
    start = clock.now()  # (read by a watchdog that trips before time 0 below)
    if watchdog is not None:
        # Before time 0: starting a thread takes ~0.4 ms (its stack mapped and, in a servo process with locked
        # memory, faulted in; the new thread runs once at the loop's priority), which inside the first period made
        # the first tick late by more than 1 ms on a loaded machine (3 of 12 servo runs of the bench loop at load 10-31)
        watchdog.start()
    start = clock.now()
    if on_start is not None:
        on_start(start)
    if watchdog is not None:
        watchdog.kick()
    percept: dict[str, Any] = {}
    scans = 0
    reports: list[dict[str, Any]] = []
    ticks = 0
    ended_by = "time_limit"
    last_inputs: Mapping[str, float] = {}
    diagnostics: Mapping[str, float] = getattr(controller, "diagnostics", None) or {}
    controller_events: list[dict[str, Any]] | None = getattr(controller, "events", None)
    emit(0.0, "trial_loop_start", {"rate_hz": info.rate_hz})
    # Hot loop: bind what is used every tick to locals (a 1 kHz loop spends its budget on lookups).
    time_limit = info.time_limit_s
    on_request = info.visual == "on_request"
    realtime = info.visual == "realtime" and view is not None
    # a scene's view_parts(inputs, observation, diagnostics) draws the same frame without the merged dict
    view_parts = getattr(getattr(view, "__self__", None), "view_parts", None) if realtime else None
    now = clock.now
    sleep_until = clock.sleep_until
    act = participant.act
    apply_input = device.apply_input
    read = device.read
    write = device.write
    feedback = device.feedback
    step = controller.step if controller is not None else None
    safety_filter = safety.filter
    # The safety layer's fault causes (mutated in place, never rebound): fault_duration is only asked while
    # a fault holds the device safe.
    fault_causes = safety._fault_causes
    try:
        while True:
            t = now() - start
            if t >= time_limit:
                ended_by = "time_limit"
                break
            if should_stop is not None:
                reason = should_stop()
                if reason:
                    ended_by = reason
                    break
            action = act(t, percept)
            inputs = action.inputs
            if inputs:
                apply_input(inputs)
                last_inputs = inputs
            try:
                obs = read(t)
            except DeviceError as exc:
                emit(t, "device_fault", {"rule": "read_failed", "error": str(exc)})
                ended_by = "fault"
                break
            command = step(obs) if step is not None else {}
            written = safety_filter(command, t, obs)  # what the device actually gets, logged below
            write(written)
            if watchdog is not None:
                watchdog.kick()
            if safety.events:  # drain (a lock) only when there is something to drain
                for ev in safety.drain_events():
                    emit(ev["t"], ev["kind"], {k: v for k, v in ev.items() if k not in ("t", "kind")})
            if controller_events:
                for ev in controller_events:
                    emit(t, str(ev.get("kind", "controller")), {k: v for k, v in ev.items() if k != "kind"})
                controller_events.clear()
            if fault_causes and safety.fault_duration(t) >= FAULT_ABORT_S:
                ended_by = "fault"
                break
            percept = dict(feedback())
            values = obs.values
            finished = False
            for request in action.requests:  # usually none
                if request.kind == "scan":
                    if on_request:
                        scans += 1
                        pose = {**last_inputs, **values, **diagnostics}
                        frame = view(pose) if view is not None else None
                        percept["scan"] = frame
                        emit(t, "scan", {"count": scans, "pose": pose})
                elif request.kind == "report":
                    report = {"t": t, **request.payload}
                    reports.append(report)
                    emit(t, "report", dict(request.payload))
                elif request.kind == "finish":
                    finished = True
            if realtime:
                if view_parts is not None:
                    percept["view"] = view_parts(last_inputs, values, diagnostics)
                else:
                    percept["view"] = view({**last_inputs, **values, **diagnostics})
            if on_sample_parts is not None:
                on_sample_parts(t, values, written, diagnostics)
            elif on_sample is not None:
                on_sample(t, {**values, **written, **diagnostics})
            ticks += 1
            if finished:
                ended_by = "finish"
                break
            sleep_until(start + ticks * period)
    finally:
        if watchdog is not None:
            watchdog.stop()
        device.write(safety.safe_command())
        for ev in safety.drain_events():
            emit(ev["t"], ev["kind"], {k: v for k, v in ev.items() if k not in ("t", "kind")})
    duration = min(clock.now() - start, info.time_limit_s)
    emit(duration, "trial_loop_end", {"ended_by": ended_by, "ticks": ticks})
    return TrialOutcome(ended_by, duration, ticks, scans, reports, events)
