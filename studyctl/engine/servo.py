"""Run a trial's 1 kHz loop in its own process, away from the user interface and logging.

A Python servo thread shares the interpreter lock with everything else in its process; next to one busy
thread its p99 period grew to ~8 ms on this kind of machine (research/haptics.md). So for hardware the
whole trial loop (device, controller, safety layer) runs in a spawned child process with a real clock;
the parent only forwards the participant's requests (scan, finish) and stop signals, and receives the
samples and events in small batches to store them. The child measures its own pacing and logs a
``servo_timing`` event: tick lateness against the schedule and period jitter (|period − T|) percentiles.

Everything the child needs travels as plain data (:class:`ServoSpec`: plugin names and parameters, the
scene's spec and placement), so plugins are rebuilt in the child through the same entry points.
"""

from __future__ import annotations

import logging
import math
import multiprocessing as mp
import os
import queue
import time
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from studyctl.engine.clock import RealClock
from studyctl.engine.trial_loop import run_trial
from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo
from studyctl.plugins.registry import load_plugin

BATCH_S = 0.016  # samples reach the parent at about the display rate


@dataclass(frozen=True)
class ServoSpec:
    """What the servo process builds: plugins by entry-point name with their parameters."""

    info: TrialInfo
    device: str
    device_params: Mapping[str, Any] = field(default_factory=dict)
    controller: str | None = None
    controller_params: Mapping[str, Any] = field(default_factory=dict)
    scene: str | None = None
    scene_spec: Mapping[str, Any] = field(default_factory=dict)
    scene_placement: Mapping[str, Any] = field(default_factory=dict)
    scene_needs: frozenset[str] = frozenset()
    participant: str | None = None  # a virtual participant in the child; None: requests come from the parent
    participant_params: Mapping[str, Any] = field(default_factory=dict)
    seed: int = 0
    nice: int = -10  # scheduling priority for the servo process (best effort; 0 leaves it unchanged)


@dataclass(frozen=True)
class ServoTiming:
    """Pacing of a real-time loop: lateness of tick starts and period jitter, in microseconds."""

    ticks: int
    period_us: float
    late_us_p50: float
    late_us_p99: float
    late_us_max: float
    period_jitter_us_p50: float
    period_jitter_us_p99: float
    period_jitter_us_max: float
    overruns: int  # ticks that started more than one period late

    @classmethod
    def from_starts(cls, starts: np.ndarray, period_s: float, scheduled: np.ndarray | None = None) -> ServoTiming:
        """Timing from the tick start times (s) of a loop scheduled every ``period_s``.

        ``scheduled`` are the times each tick was due (default: the first start plus whole periods).
        """
        starts = np.asarray(starts, dtype=float)
        if len(starts) < 2:
            return cls(len(starts), period_s * 1e6, *([math.nan] * 6), 0)
        if scheduled is None:
            scheduled = starts[0] + period_s * np.arange(len(starts))
        late = (starts - np.asarray(scheduled, dtype=float)) * 1e6
        jitter = np.abs(np.diff(starts) - period_s) * 1e6
        return cls(
            ticks=len(starts),
            period_us=period_s * 1e6,
            late_us_p50=float(np.percentile(late, 50)),
            late_us_p99=float(np.percentile(late, 99)),
            late_us_max=float(late.max()),
            period_jitter_us_p50=float(np.percentile(jitter, 50)),
            period_jitter_us_p99=float(np.percentile(jitter, 99)),
            period_jitter_us_max=float(jitter.max()),
            overruns=int(np.sum(late > period_s * 1e6)),
        )

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


class TimedClock(RealClock):
    """A real clock that records when each tick actually started (the return of ``sleep_until``)."""

    def __init__(self, capacity: int = 1 << 20) -> None:
        super().__init__()
        self.starts = np.empty(capacity)
        self.due = np.empty(capacity)
        self.n = 0

    def sleep_until(self, t: float) -> None:
        super().sleep_until(t)
        if self.n < len(self.starts):
            self.starts[self.n] = self.now()
            self.due[self.n] = t
            self.n += 1

    def timing(self, period_s: float) -> ServoTiming:
        """Lateness against each tick's due time and period jitter of the ticks recorded so far."""
        return ServoTiming.from_starts(self.starts[: self.n], period_s, self.due[: self.n])


class _RemoteParticipant(Participant):
    """Stands in for the person in the servo process: requests arrive from the parent over a queue."""

    name = "remote"
    virtual = False

    def __init__(self, inbox: Any, poll_every: int) -> None:
        super().__init__({})
        self.inbox = inbox
        self.poll_every = poll_every
        self.stop_reason: str | None = None
        self._k = 0
        self._idle = Action()

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self._k = 0

    def poll(self) -> list[Request]:
        out: list[Request] = []
        while True:
            try:
                kind, payload = self.inbox.get_nowait()
            except queue.Empty:
                return out
            if kind == "stop":
                self.stop_reason = str(payload)
            else:
                out.append(Request(kind, payload or {}))

    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        self._k += 1
        if self._k < self.poll_every:
            return self._idle
        self._k = 0
        requests = self.poll()
        return Action({}, tuple(requests)) if requests else self._idle


def _construct(cls: type, **kwargs: Any) -> Any:
    import inspect  # noqa: PLC0415

    params = inspect.signature(cls).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return cls(**kwargs)
    return cls(**{k: v for k, v in kwargs.items() if k in params})


def _servo_main(spec: ServoSpec, inbox: Any, outbox: Any) -> None:
    """The child process: build the plugins, run the trial on a real clock, stream everything back."""
    # Safety events travel to the parent as events; printing each one here would cost the loop its time.
    quiet = logging.getLogger("studyctl")
    quiet.addHandler(logging.NullHandler())
    quiet.propagate = False
    try:
        niced = 0
        if spec.nice:
            try:  # a haptic servo runs above the UI, as CHAI3D's haptics thread does; needs the privilege
                niced = _renice(spec.nice)
            except OSError:
                niced = 0
        rng = np.random.default_rng(spec.seed)
        scene = None
        if spec.scene:
            scene = load_plugin("scene", spec.scene).build(
                dict(spec.scene_spec), dict(spec.scene_placement), frozenset(spec.scene_needs), rng
            )
        controller = None
        if spec.controller:
            controller = load_plugin("controller", spec.controller)(dict(spec.controller_params), scene)
        device = _construct(load_plugin("device", spec.device), params=dict(spec.device_params), scene=scene, rng=rng)
        remote = _RemoteParticipant(inbox, poll_every=max(1, round(spec.info.rate_hz * 0.01)))
        if spec.participant:
            participant = _construct(load_plugin("participant", spec.participant), params=dict(spec.participant_params))
        else:
            participant = remote
        batch: list[tuple[float, tuple[float, ...]]] = []
        names: list[tuple[str, ...]] = [()]
        last_flush = [time.perf_counter()]

        def flush() -> None:
            if batch:
                outbox.put(("samples", names[0], list(batch)))
                batch.clear()
            last_flush[0] = time.perf_counter()

        def on_sample(t: float, values: Mapping[str, float]) -> None:
            keys = tuple(values)
            if keys != names[0]:
                flush()
                names[0] = keys
            batch.append((t, tuple(values.values())))
            if time.perf_counter() - last_flush[0] >= BATCH_S:
                flush()

        def on_event(t: float, kind: str, payload: Mapping[str, Any]) -> None:
            flush()
            outbox.put(("event", t, kind, _plain(payload)))

        ticks = [0]

        def should_stop() -> str | None:
            if participant is not remote:  # a virtual participant: only stop signals come from the parent
                ticks[0] += 1
                if ticks[0] >= remote.poll_every:
                    ticks[0] = 0
                    remote.poll()
            return remote.stop_reason

        clock = TimedClock(capacity=int(spec.info.time_limit_s * spec.info.rate_hz) + 16)
        device.open()
        try:
            outcome = run_trial(
                info=spec.info,
                controller=controller,
                device=device,
                participant=participant,
                clock=clock,
                rng=rng,
                on_event=on_event,
                on_sample=on_sample,
                view=scene.view if (scene is not None and spec.participant) else None,
                should_stop=should_stop,
            )
        finally:
            device.close()
        flush()
        timing = clock.timing(1.0 / spec.info.rate_hz)
        outbox.put(("event", outcome.duration_s, "servo_timing", {**timing.as_dict(), "nice": niced}))
        outbox.put(("outcome", _plain(outcome.__dict__)))
    except BaseException as exc:  # the parent must learn why the child ended
        outbox.put(("error", f"{type(exc).__name__}: {exc}", traceback.format_exc()))


def _renice(delta: int) -> int:
    """Change this process's niceness by ``delta``; return the change actually made."""
    before = os.nice(0)
    return os.nice(delta) - before


def _plain(value: Any) -> Any:
    """Picklable, plain copies of event payloads (frames and arrays are dropped)."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items() if not hasattr(v, "__array__") or np.ndim(v) == 0}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value


@dataclass
class ServoResult:
    """The trial outcome as the child reported it, with the child's pacing statistics."""

    ended_by: str
    duration_s: float
    ticks: int
    scans: int
    reports: list[dict[str, Any]]
    events: list[dict[str, Any]]
    timing: ServoTiming | None


def run_trial_in_servo_process(
    spec: ServoSpec,
    *,
    on_event: Callable[[float, str, Mapping[str, Any]], None] | None = None,
    on_sample: Callable[[float, Mapping[str, float]], None] | None = None,
    requests: Callable[[], list[Request]] | None = None,
    should_stop: Callable[[], str | None] | None = None,
    poll_s: float = 0.005,
    start_timeout_s: float = 60.0,
) -> ServoResult:
    """Run one trial in a spawned servo process; call the sinks here, in the parent, as data arrives.

    ``requests`` is polled every ``poll_s`` for the person's requests (scan, report, finish), which are
    forwarded to the loop; ``should_stop`` likewise (a reason string ends the trial). Raises
    :class:`~studyctl.errors.DeviceError` if the child fails (its traceback is in the message).
    """
    ctx = mp.get_context("spawn")
    inbox, outbox = ctx.Queue(), ctx.Queue()
    proc = ctx.Process(target=_servo_main, args=(spec, inbox, outbox), name="studyctl-servo", daemon=True)
    proc.start()
    outcome: dict[str, Any] | None = None
    timing: ServoTiming | None = None
    error: tuple[str, str] | None = None
    started = time.monotonic()
    stop_sent = False
    try:
        while outcome is None and error is None:
            if requests is not None:
                for r in requests():
                    inbox.put((r.kind, dict(r.payload)))
            if should_stop is not None and not stop_sent:
                reason = should_stop()
                if reason:
                    inbox.put(("stop", reason))
                    stop_sent = True
            try:
                msg = outbox.get(timeout=poll_s)
            except queue.Empty:
                if not proc.is_alive():
                    error = ("servo process ended without a result", f"exit code {proc.exitcode}")
                elif time.monotonic() - started > start_timeout_s + spec.info.time_limit_s:
                    error = ("servo process did not finish in time", "")
                continue
            kind = msg[0]
            if kind == "samples" and on_sample is not None:
                names = msg[1]
                for t, row in msg[2]:
                    on_sample(t, dict(zip(names, row, strict=True)))
            elif kind == "event":
                _, t, ev_kind, payload = msg
                if ev_kind == "servo_timing":
                    timing = ServoTiming(**{k: v for k, v in payload.items() if k != "nice"})
                if on_event is not None:
                    on_event(t, ev_kind, payload)
            elif kind == "outcome":
                outcome = msg[1]
            elif kind == "error":
                error = (msg[1], msg[2])
    finally:
        proc.join(timeout=5.0)
        if proc.is_alive():
            proc.terminate()
            proc.join(timeout=2.0)
    if error is not None or outcome is None:
        what, detail = error or ("no outcome", "")
        raise DeviceError(f"servo process failed: {what}\n{detail}")
    return ServoResult(
        ended_by=outcome["ended_by"],
        duration_s=outcome["duration_s"],
        ticks=outcome["ticks"],
        scans=outcome["scans"],
        reports=outcome["reports"],
        events=outcome["events"],
        timing=timing,
    )
