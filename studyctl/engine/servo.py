"""Run a trial's 1 kHz loop in its own process, away from the user interface and logging.

A Python servo thread shares the interpreter lock with everything else in its process; next to one busy
thread its p99 period grew to ~8 ms on this kind of machine (research/haptics.md). So for hardware the
whole trial loop (device, controller, safety layer) runs in a spawned child process with a real clock;
the parent only forwards the participant's requests (scan, finish) and stop signals, and receives the
samples and events in small batches to store them. The child measures its own pacing and logs a
``servo_timing`` event: tick lateness against the schedule and period jitter (|period − T|) percentiles.

Everything the child needs travels as plain data (:class:`ServoSpec`: plugin names and parameters, the
scene's spec and placement, the trial's random generators), so plugins are rebuilt in the child through the
same entry points.

Real-time hygiene in the child (:func:`realtime_setup`): garbage collection is frozen and disabled for the
trial (a collection of the young generation can take milliseconds), buffers are preallocated (tick times,
the sample batch), the wait is hybrid (sleep until ~0.3 ms before the tick, then spin), the process is pinned
to one CPU and asks for the highest scheduling priority the OS grants (SCHED_FIFO when permitted, else a
lower nice value). What it actually got is measured and reported in the ``servo_timing`` event (``rt``).

Faults: if the parent dies the child notices within ~10 ms (its parent pid changes), ends the trial and puts
the device in its safe state; if the child dies the parent raises :class:`~studyctl.errors.DeviceError`
after putting the device in its safe state from its side (:func:`make_device_safe`), so the engine records
the trial as aborted and the session stays resumable.
"""

from __future__ import annotations

import contextlib
import gc
import logging
import math
import multiprocessing as mp
import os
import queue
import sys
import time
import traceback
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from studyctl.engine.clock import RealClock
from studyctl.engine.trial_loop import run_trial
from studyctl.errors import DeviceError, StudyctlError
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
    # a session's virtual participant in the child (run --rehearse --virtual): the same person in every trial
    # (begin_session from the session seed's person stream) with what it learnt so far (recall); its memory at the
    # end of the trial travels back to the parent
    session_seed: int | None = None
    participant_memory: Mapping[str, Any] | None = None
    # the emulator's world for the participant's hand ({kind, block}; studyctl.devices.world)
    world: Mapping[str, Any] | None = None
    seed: int = 0
    nice: int = -10  # scheduling priority for the servo process (best effort; 0 leaves it unchanged)
    # The trial's random streams (Generators pickle with their state); None: from ``seed``.
    scene_rng: np.random.Generator | None = None
    device_rng: np.random.Generator | None = None
    participant_rng: np.random.Generator | None = None
    realtime: bool = True  # gc freeze, CPU affinity, SCHED_FIFO/nice (see realtime_setup)
    cpu: int | None = None  # CPU to pin the loop to (None: the last one this process may use)
    parent_pid: int = 0  # set by run_trial_in_servo_process: the child stops when its parent goes away


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
    late_1ms: int = 0  # ticks that started more than 1 ms after they were due

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
            late_1ms=int(np.sum(late > 1000.0)),
        )

    def as_dict(self) -> dict[str, float]:
        return {k: getattr(self, k) for k in self.__dataclass_fields__}


SPIN_S = 0.0003  # the hybrid wait sleeps until this long before a tick is due, then spins
# SCHED_FIFO priority of the loop: above every normal process, below the kernel's own threads at 99
FIFO_PRIORITY = 80
SWITCH_INTERVAL_S = 1e-4


class TimedClock(RealClock):
    """A real clock with a hybrid sleep/spin wait that records when each tick actually started.

    The tick times go into preallocated arrays (no allocation per tick)."""

    def __init__(self, capacity: int = 1 << 20, spin_s: float = SPIN_S) -> None:
        super().__init__()
        self.starts = np.empty(capacity)
        self.due = np.empty(capacity)
        self.n = 0
        self.spin_s = spin_s

    def sleep_until(self, t: float) -> None:
        now = self.now
        remaining = t - now()
        if remaining > self.spin_s:
            time.sleep(remaining - self.spin_s)
        while now() < t:
            pass
        if self.n < len(self.starts):
            self.starts[self.n] = now()
            self.due[self.n] = t
            self.n += 1

    def timing(self, period_s: float) -> ServoTiming:
        """Lateness against each tick's due time and period jitter of the ticks recorded so far."""
        return ServoTiming.from_starts(self.starts[: self.n], period_s, self.due[: self.n])


class _RemoteParticipant(Participant):
    """Stands in for the person in the servo process: requests arrive from the parent over a queue."""

    name = "remote"
    virtual = False

    def __init__(self, inbox: Any, poll_every: int, parent_pid: int = 0) -> None:
        super().__init__({})
        self.inbox = inbox
        self.poll_every = poll_every
        self.parent_pid = parent_pid
        self.stop_reason: str | None = None
        self._k = 0
        self._idle = Action()

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self._k = 0

    def poll(self) -> list[Request]:
        out: list[Request] = []
        if self.parent_pid and os.getppid() != self.parent_pid and self.stop_reason is None:
            self.stop_reason = "abort"  # the parent died: end the trial, the device goes to its safe state
            return out
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


def _load(kind: str, name: str) -> type:
    """A plugin by entry-point name, or a class by ``module:Class`` (tools such as ``studyctl device check``)."""
    if ":" in name:
        import importlib  # noqa: PLC0415

        module, _, attr = name.partition(":")
        return getattr(importlib.import_module(module), attr)


    return load_plugin(kind, name)


def realtime_setup(cpu: int | None = None, nice: int = -10) -> dict[str, Any]:
    """Give this process the best real-time footing the OS allows; return what it actually got.

    Pins the process to one CPU (``cpu``, default the last allowed one), asks for SCHED_FIFO at the
    highest priority (needs root or CAP_SYS_NICE; else lowers the nice value by ``-nice`` as far as
    permitted), and freezes then disables the garbage collector. Every step is best effort: the report
    says which took effect, measured after the fact (``sched``, ``priority``, ``nice``, ``cpus``, ``gc``).
    """
    report: dict[str, Any] = {}
    if hasattr(os, "sched_setaffinity"):
        try:
            allowed = sorted(os.sched_getaffinity(0))
            target = cpu if cpu is not None and cpu in allowed else allowed[-1]
            os.sched_setaffinity(0, {target})
        except OSError:
            pass
        report["cpus"] = sorted(os.sched_getaffinity(0))
    fifo = False
    if hasattr(os, "SCHED_FIFO"):
        try:
            # RESET_ON_FORK: threads started later (queue feeder, watchdog) run at normal priority, so they never
            # hold the loop's CPU at equal priority while it waits to run
            policy = os.SCHED_FIFO | getattr(os, "SCHED_RESET_ON_FORK", 0)
            os.sched_setscheduler(0, policy, os.sched_param(FIFO_PRIORITY))
            fifo = True
        except (OSError, PermissionError):
            fifo = False
    if not fifo and nice:
        with contextlib.suppress(OSError):
            _renice(nice)
    if hasattr(os, "sched_getscheduler"):
        policy = os.sched_getscheduler(0)
        policy &= ~getattr(os, "SCHED_RESET_ON_FORK", 0)
        names = {getattr(os, n): n for n in ("SCHED_OTHER", "SCHED_FIFO", "SCHED_RR", "SCHED_BATCH", "SCHED_IDLE")
                 if hasattr(os, n)}
        report["sched"] = names.get(policy, str(policy))
        report["priority"] = os.sched_getparam(0).sched_priority
    report["nice"] = os.nice(0)
    # A helper thread holding the interpreter lock when the loop wakes is asked to drop it after this interval
    # (default 5 ms: a whole tick and more lost)
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    report["switch_interval_us"] = sys.getswitchinterval() * 1e6
    gc.collect()
    gc.freeze()  # everything allocated so far is never scanned again
    gc.disable()  # and nothing new is collected until the trial ends
    report["gc"] = "frozen+disabled"
    return report


def _servo_main(spec: ServoSpec, inbox: Any, outbox: Any) -> None:
    """The child process: build the plugins, run the trial on a real clock, stream everything back."""
    # Safety events travel to the parent as events; printing each one here would cost the loop its time.
    quiet = logging.getLogger("studyctl")
    quiet.addHandler(logging.NullHandler())
    quiet.propagate = False
    device = None
    try:
        rng = np.random.default_rng(spec.seed)
        scene = None
        if spec.scene:
            scene = load_plugin("scene", spec.scene).build(
                dict(spec.scene_spec), dict(spec.scene_placement), frozenset(spec.scene_needs),
                spec.scene_rng if spec.scene_rng is not None else rng,
            )
        controller = None
        if spec.controller:
            controller = _load("controller", spec.controller)(dict(spec.controller_params), scene)
        device = _construct(load_plugin("device", spec.device), params=dict(spec.device_params), scene=scene,
                            rng=spec.device_rng if spec.device_rng is not None else rng)
        if spec.world:  # a virtual participant's hand in the emulator's world (studyctl.devices.world)
            from studyctl.devices.world import embody  # noqa: PLC0415

            device = embody(device, spec.world, scene)
        remote = _RemoteParticipant(inbox, poll_every=max(1, round(spec.info.rate_hz * 0.01)),
                                    parent_pid=spec.parent_pid)
        if spec.participant:
            participant = _construct(load_plugin("participant", spec.participant), params=dict(spec.participant_params))
            _continue_person(participant, spec)
        else:
            participant = remote
        # The sample batch is a preallocated ring of rows flushed every BATCH_S (no list growth per tick).
        cap = max(64, int(spec.info.rate_hz * BATCH_S * 4) + 8)
        rows: list[Any] = [None] * cap
        fill = [0]
        names: list[tuple[str, ...]] = [()]
        last_flush = [time.perf_counter()]

        def flush() -> None:
            n = fill[0]
            if n:
                outbox.put(("samples", names[0], rows[:n]))
                fill[0] = 0
            last_flush[0] = time.perf_counter()

        def on_sample(t: float, values: Mapping[str, float]) -> None:
            keys = tuple(values)
            if keys != names[0]:
                flush()
                names[0] = keys
            rows[fill[0]] = (t, tuple(values.values()))
            fill[0] += 1
            if fill[0] >= cap or time.perf_counter() - last_flush[0] >= BATCH_S:
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
        identity = getattr(device, "identity", None)
        if callable(identity):  # what the device says it is (model, serial, firmware): for the record
            outbox.put(("event", 0.0, "device_identity", _plain(dict(identity()))))
        rt: dict[str, Any] = realtime_setup(spec.cpu, spec.nice) if spec.realtime else {}
        cpu0 = time.process_time()
        # trial time 0 on the monotonic clock (LSL's local_clock), so the parent can place batched samples in time
        outbox.put(("event", 0.0, "servo_clock", {"monotonic_zero": time.monotonic()}))
        try:
            outcome = run_trial(
                info=spec.info,
                controller=controller,
                device=device,
                participant=participant,
                clock=clock,
                rng=spec.participant_rng if spec.participant_rng is not None else rng,
                on_event=on_event,
                on_sample=on_sample,
                view=scene.view if (scene is not None and spec.participant) else None,
                should_stop=should_stop,
            )
        finally:
            if spec.realtime:
                gc.enable()
                gc.unfreeze()
            device.close()
        flush()
        rt["cpu_s"] = time.process_time() - cpu0
        timing = clock.timing(1.0 / spec.info.rate_hz)
        outbox.put(("event", outcome.duration_s, "servo_timing", {**timing.as_dict(), "rt": rt,
                                                                    "nice": rt.get("nice", 0)}))
        memory = getattr(participant, "memory", None)
        if spec.participant and callable(memory):
            outbox.put(("memory", _plain(dict(memory() or {}))))
        outbox.put(("outcome", _plain(outcome.__dict__)))
    except BaseException as exc:  # the parent must learn why the child ended
        if device is not None:
            with contextlib.suppress(Exception):
                device.close()  # safe state: close() commands it and must be safe to call twice
        user = isinstance(exc, StudyctlError)
        outbox.put(("error", f"{type(exc).__name__}: {exc}" if not user else str(exc),
                    "" if user else traceback.format_exc()))


def _continue_person(participant: Participant, spec: ServoSpec) -> None:
    """Make the child's virtual participant the session's person: its traits from the session seed's person stream
    and what it had learnt by the previous trial (as SessionRunner.run does for an in-process participant)."""
    if spec.session_seed is not None:
        begin_session = getattr(participant, "begin_session", None)
        if callable(begin_session):
            from studyctl.engine.seeding import person_rng  # noqa: PLC0415

            begin_session(person_rng(spec.session_seed))
    recall = getattr(participant, "recall", None)
    if spec.participant_memory and callable(recall):
        recall(dict(spec.participant_memory))


def _renice(delta: int) -> int:
    """Change this process's niceness by ``delta``; return the change actually made."""
    before = os.nice(0)
    return os.nice(delta) - before


def make_device_safe(spec: ServoSpec) -> str | None:
    """From the parent, after the servo child died: open the device and close it again, which commands its safe
    state (the device's own watchdog is the backstop when this fails). Returns None or why it could not."""


    try:
        device = _construct(load_plugin("device", spec.device), params=dict(spec.device_params), scene=None,
                            rng=np.random.default_rng(0))
        device.open()
        device.close()
    except Exception as exc:  # the device may be the reason the child died
        return f"{type(exc).__name__}: {exc}"
    return None


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
    rt: dict[str, Any] = field(default_factory=dict)
    memory: dict[str, Any] | None = None  # a virtual participant's memory at the end of the trial (child participant)
    start_s: float = float("nan")  # wall seconds from starting the process to the trial's time 0 (spawn, imports, open)


_TIMING_FIELDS = frozenset(ServoTiming.__dataclass_fields__)


@contextlib.contextmanager
def _main_not_rerun():
    """Start a spawned child without running this process's main script again in it.

    ``spawn`` re-runs the parent's ``__main__`` in the child when it is a script (the ``studyctl`` console script
    imports the whole CLI: typer, rich, pandas, pyarrow, SQLAlchemy, the participant view; ~1 s of CPU and ~50 MB per
    trial). The servo needs none of it: its target and spec come from importable modules. The preparation data are
    taken while ``start()`` runs, so the main module's ``__file__`` is hidden only for that moment."""
    main = sys.modules.get("__main__")
    if main is None or getattr(main, "__spec__", None) is not None or not hasattr(main, "__file__"):
        yield  # `python -m studyctl` (a module main is never re-run) or an interactive session
        return
    path = main.__file__
    del main.__file__
    try:
        yield
    finally:
        main.__file__ = path


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
    :class:`~studyctl.errors.DeviceError` if the child fails (a plugin bug's traceback is in the message; a
    device's own error is passed on as it is) or dies; the device is then put in its safe state from here.
    """
    if not spec.parent_pid:
        from dataclasses import replace  # noqa: PLC0415

        spec = replace(spec, parent_pid=os.getpid())
    ctx = mp.get_context("spawn")
    inbox, outbox = ctx.Queue(), ctx.Queue()
    proc = ctx.Process(target=_servo_main, args=(spec, inbox, outbox), name="studyctl-servo", daemon=True)
    with _main_not_rerun():
        proc.start()
    outcome: dict[str, Any] | None = None
    timing: ServoTiming | None = None
    rt: dict[str, Any] = {}
    memory: dict[str, Any] | None = None
    start_s = float("nan")
    error: tuple[str, str] | None = None
    died = False
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
                    try:  # its last messages may still be on their way through the pipe
                        msg = outbox.get(timeout=1.0)
                    except queue.Empty:
                        died = True
                        error = (f"the servo process ended without a result (exit code {proc.exitcode})", "")
                        continue
                elif time.monotonic() - started > start_timeout_s + spec.info.time_limit_s:
                    error = ("the servo process did not finish in time", "")
                    continue
                else:
                    continue
            kind = msg[0]
            if kind == "samples" and on_sample is not None:
                names = msg[1]
                for t, row in msg[2]:
                    on_sample(t, dict(zip(names, row, strict=True)))
            elif kind == "event":
                _, t, ev_kind, payload = msg
                if ev_kind == "servo_clock":
                    start_s = time.monotonic() - started
                if ev_kind == "servo_timing":
                    timing = ServoTiming(**{k: v for k, v in payload.items() if k in _TIMING_FIELDS})
                    rt = dict(payload.get("rt") or {})
                if on_event is not None:
                    on_event(t, ev_kind, payload)
            elif kind == "memory":
                memory = msg[1]
            elif kind == "outcome":
                outcome = msg[1]
            elif kind == "error":
                error = (msg[1], msg[2])
    except BaseException:
        inbox.put(("stop", "abort"))  # Ctrl-C or a failing sink in the parent: the child ends the trial safely
        raise
    finally:
        proc.join(timeout=5.0)
        if proc.is_alive():
            proc.terminate()
            proc.join(timeout=2.0)
    if error is not None or outcome is None:
        what, detail = error or ("no outcome", "")
        if died or detail:
            why = make_device_safe(spec)
            what += " (safe state commanded from this process)" if why is None else (
                f"; putting the device in its safe state from here failed ({why}), its own watchdog is the backstop")
        if not died and not detail:  # the device's own error (absent, busy …), already worded for the user
            raise DeviceError(what)
        raise DeviceError(f"servo process failed: {what}" + (f"\n{detail}" if detail else ""))
    return ServoResult(
        ended_by=outcome["ended_by"],
        duration_s=outcome["duration_s"],
        ticks=outcome["ticks"],
        scans=outcome["scans"],
        reports=outcome["reports"],
        events=outcome["events"],
        timing=timing,
        rt=rt,
        memory=memory,
        start_s=start_s,
    )
