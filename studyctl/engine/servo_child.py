"""The servo process's side: wait for trials, build each trial's plugins, run its loop on a real clock, stream samples
and events back.

One process serves a whole session (:class:`studyctl.engine.servo.ServoProcess`): it is spawned once and then runs
the trials it is sent, one at a time. Messages travel over two one-way pipes, written by the loop's own thread (no
queue feeder thread in this process, whose interpreter-lock turns on a loaded machine would cost the loop its ticks).
Every message carries the trial's number, so a late request or stop meant for an earlier trial never reaches the
next one.

parent → child: ``("trial", n, spec)``, ``("request", n, kind, payload)``, ``("stop", n, reason)``, ``("quit",)``.
child → parent: ``(n, "samples", names, rows)``, ``(n, "event", t, kind, payload)``, ``(n, "memory", dict)``,
``(n, "outcome", dict)``, ``(n, "error", message, traceback)``.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
import traceback
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from studyctl.engine.realtime import TimedClock, cpu_steal_ms, realtime_release, realtime_setup
from studyctl.engine.trial_loop import run_trial
from studyctl.errors import StudyctlError
from studyctl.plugins.interfaces import Action, Participant, Request, TrialInfo
from studyctl.plugins.registry import load_plugin

if TYPE_CHECKING:
    from studyctl.engine.servo import ServoSpec

BATCH_S = 0.016  # samples reach the parent at about the display rate
IDLE_POLL_S = 0.05  # between trials: how often the child checks that its parent is still there


class _RemoteParticipant(Participant):
    """Stands in for the person in the servo process: requests arrive from the parent over the inbox pipe."""

    name = "remote"
    virtual = False

    def __init__(self, inbox: Any, trial: int, poll_every: int, parent_pid: int = 0) -> None:
        super().__init__({})
        self.inbox = inbox
        self.trial = trial
        self.poll_every = poll_every
        self.parent_pid = parent_pid
        self.stop_reason: str | None = None
        self.quit = False  # the parent asked the process to end (after this trial)
        self._k = 0
        self._idle = Action()

    def begin_trial(self, info: TrialInfo, rng: np.random.Generator) -> None:
        self._k = 0

    def poll(self) -> list[Request]:
        out: list[Request] = []
        if self.parent_pid and os.getppid() != self.parent_pid and self.stop_reason is None:
            self.stop_reason = "abort"  # the parent died: end the trial, the device goes to its safe state
            return out
        inbox = self.inbox
        while inbox.poll():
            msg = inbox.recv()
            if msg[0] == "quit":
                self.quit = True
                self.stop_reason = self.stop_reason or "abort"
            elif msg[1] != self.trial:  # meant for an earlier trial
                continue
            elif msg[0] == "stop":
                self.stop_reason = str(msg[2])
            elif msg[0] == "request":
                out.append(Request(msg[2], msg[3] or {}))
        return out

    def act(self, t: float, percept: Mapping[str, Any]) -> Action:
        self._k += 1
        if self._k < self.poll_every:
            return self._idle
        self._k = 0
        requests = self.poll()
        return Action({}, tuple(requests)) if requests else self._idle


def construct(cls: type, **kwargs: Any) -> Any:
    """``cls(**kwargs)`` with only the keywords its constructor takes."""
    import inspect  # noqa: PLC0415

    params = inspect.signature(cls).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return cls(**kwargs)
    return cls(**{k: v for k, v in kwargs.items() if k in params})


def load(kind: str, name: str) -> type:
    """A plugin by entry-point name, or a class by ``module:Class`` (tools such as ``studyctl device check``)."""
    if ":" in name:
        import importlib  # noqa: PLC0415

        module, _, attr = name.partition(":")
        return getattr(importlib.import_module(module), attr)
    return load_plugin(kind, name)


def servo_main(inbox: Any, outbox: Any, parent_pid: int) -> None:
    """The servo process: run the trials the parent sends until it says quit or goes away."""
    # Safety events travel to the parent as events; printing each one here would cost the loop its time.
    quiet = logging.getLogger("studyctl")
    quiet.addHandler(logging.NullHandler())
    quiet.propagate = False
    pipe_kib = widen_pipe(outbox)
    served = 0
    while True:
        if parent_pid and os.getppid() != parent_pid:
            return  # the parent died between trials: nothing is open
        if not inbox.poll(IDLE_POLL_S):
            continue
        try:
            msg = inbox.recv()
        except EOFError:
            return
        if msg[0] == "quit":
            return
        if msg[0] != "trial":
            continue  # a request or stop that arrived after its trial ended
        served += 1
        if run_one(msg[2], msg[1], inbox, outbox, parent_pid, served, pipe_kib):
            return


PIPE_BYTES = 1 << 20  # ~5 s of 1 kHz samples


def widen_pipe(conn: Any) -> int:
    """Grow the pipe the loop writes into to :data:`PIPE_BYTES` (or the system's limit, fs.pipe-max-size): the loop
    blocks when it is full, which a parent starved by a loaded machine (no reads for ~0.3 s at the default 64 KiB)
    otherwise turns into a stall of the loop itself. Returns the size it got (KiB; 0 where unknown)."""
    try:
        import fcntl  # noqa: PLC0415

        setsz = getattr(fcntl, "F_SETPIPE_SZ", 1031)
        getsz = getattr(fcntl, "F_GETPIPE_SZ", 1032)
        try:
            with open("/proc/sys/fs/pipe-max-size") as f:
                limit = int(f.read())
        except (OSError, ValueError):
            limit = PIPE_BYTES
        fcntl.fcntl(conn.fileno(), setsz, min(PIPE_BYTES, limit))
        return fcntl.fcntl(conn.fileno(), getsz) // 1024
    except (ImportError, OSError):
        return 0


def run_one(spec: ServoSpec, n: int, inbox: Any, outbox: Any, parent_pid: int, served: int = 1,
            pipe_kib: int = 0) -> bool:
    """Build the plugins of one trial, run it on a real clock, stream everything back; True if the parent asked the
    process to end meanwhile."""
    send = outbox.send
    device = None
    remote = _RemoteParticipant(inbox, n, poll_every=max(1, round(spec.info.rate_hz * 0.01)),
                                parent_pid=spec.parent_pid or parent_pid)
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
            controller = load("controller", spec.controller)(dict(spec.controller_params), scene)
        device = construct(load_plugin("device", spec.device), params=dict(spec.device_params), scene=scene,
                           rng=spec.device_rng if spec.device_rng is not None else rng)
        if spec.world:  # a virtual participant's hand in the emulator's world (studyctl.devices.world)
            from studyctl.devices.world import embody  # noqa: PLC0415

            device = embody(device, spec.world, scene)
        if spec.participant:
            participant = construct(load_plugin("participant", spec.participant),
                                    params=dict(spec.participant_params))
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
            k = fill[0]
            if k:
                send((n, "samples", names[0], rows[:k]))
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
            send((n, "event", t, kind, plain(payload)))

        ticks = [0]

        def should_stop() -> str | None:
            if participant is not remote:  # a virtual participant: only stop signals come from the parent
                ticks[0] += 1
                if ticks[0] >= remote.poll_every:
                    ticks[0] = 0
                    remote.poll()
            return remote.stop_reason

        clock = TimedClock(capacity=int(spec.info.time_limit_s * spec.info.rate_hz) + 16)
        # before the device opens: locking memory and collecting garbage take long on a loaded machine (measured in
        # setup_ms), and an open device's own watchdog expects the loop's first command soon (the driver board's:
        # 250 ms after HELLO)
        t_setup = time.perf_counter()
        rt: dict[str, Any] = realtime_setup(spec.cpu, spec.nice) if spec.realtime else {}
        rt["setup_ms"] = (time.perf_counter() - t_setup) * 1e3
        try:
            device.open()
            identity = getattr(device, "identity", None)
            if callable(identity):  # what the device says it is (model, serial, firmware): for the record
                send((n, "event", 0.0, "device_identity", plain(dict(identity()))))
            rt["pid"], rt["trial_in_process"], rt["pipe_kib"] = os.getpid(), served, pipe_kib
            cpu0 = time.process_time()
            loop_cpu = rt["cpus"][0] if len(rt.get("cpus", ())) == 1 else None
            steal0 = cpu_steal_ms(loop_cpu)

            def monotonic_of(reading: float) -> float:
                """A reading of the loop's clock on the monotonic clock (LSL's local_clock)."""
                return time.monotonic() - (clock.now() - reading)

            def on_start(start: float) -> None:
                # trial time 0 on the monotonic clock (LSL's local_clock), so the parent can place batched samples
                # in time; taken at the loop's own time 0: taken before run_trial it preceded time 0 by the
                # participant's begin_trial, the controller's reset and the watchdog thread's start (0.19-0.36 ms,
                # tests/devices/test_lsl.py at load 3)
                send((n, "event", 0.0, "servo_clock", {"monotonic_zero": monotonic_of(start)}))

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
                on_start=on_start,
            )
        finally:
            if spec.realtime:
                realtime_release(rt)
            device.close()
        flush()
        rt["cpu_s"] = time.process_time() - cpu0
        steal1 = cpu_steal_ms(loop_cpu)
        if steal0 is not None and steal1 is not None:  # the hypervisor's share of the loop's CPU during the trial
            rt["steal_ms"] = steal1 - steal0
        if clock.n:  # when the loop's first paced tick began, on the monotonic clock (checks servo_clock's stamps)
            rt["first_tick_monotonic"] = monotonic_of(float(clock.starts[0]))
        timing = clock.timing(1.0 / spec.info.rate_hz)
        send((n, "event", outcome.duration_s, "servo_timing", {**timing.as_dict(), "rt": rt,
                                                                "nice": rt.get("nice", 0)}))
        memory = getattr(participant, "memory", None)
        if spec.participant and callable(memory):
            send((n, "memory", plain(dict(memory() or {}))))
        send((n, "outcome", plain(outcome.__dict__)))
    except BaseException as exc:  # the parent must learn why the trial ended
        if device is not None:
            with contextlib.suppress(Exception):
                device.close()  # safe state: close() commands it and must be safe to call twice
        user = isinstance(exc, StudyctlError)
        with contextlib.suppress(Exception):
            send((n, "error", f"{type(exc).__name__}: {exc}" if not user else str(exc),
                  "" if user else traceback.format_exc()))
        if not isinstance(exc, Exception):
            raise
    return remote.quit


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


def plain(value: Any) -> Any:
    """Picklable, plain copies of event payloads (frames and arrays are dropped)."""
    if isinstance(value, Mapping):
        return {str(k): plain(v) for k, v in value.items() if not hasattr(v, "__array__") or np.ndim(v) == 0}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    return value
