"""Run hardware trials' 1 kHz loops in their own process, away from the user interface and logging.

A Python servo thread shares the interpreter lock with everything else in its process; next to one busy
thread its p99 period grew to ~8 ms on this kind of machine (research/haptics.md). So for hardware the
whole trial loop (device, controller, safety layer) runs in a spawned child process with a real clock;
the parent only forwards the participant's requests (scan, finish) and stop signals, and receives the
samples and events in small batches to store them. The child measures its own pacing and logs a
``servo_timing`` event: tick lateness against the schedule and period jitter (|period − T|) percentiles.

One servo process serves a whole session (:class:`ServoProcess`): spawning one costs ~2 s of imports on a loaded
machine and the real-time setup is done again per trial anyway. Everything a trial needs travels as plain data
(:class:`ServoSpec`: plugin names and parameters, the scene's spec and placement, the trial's random generators), so
plugins are rebuilt in the child through the same entry points (:mod:`studyctl.engine.servo_child`). The child's
real-time footing (CPU pinned, SCHED_FIFO, memory locked, gc frozen) is :mod:`studyctl.engine.realtime`.

Faults: if the parent dies the child notices within ~10 ms (its parent pid changes), ends the trial and puts
the device in its safe state; if the child dies the parent raises :class:`~studyctl.errors.DeviceError`
after putting the device in its safe state from its side (:func:`make_device_safe`), so the engine records
the trial as aborted and the session stays resumable; the next trial starts a new servo process.
"""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from studyctl.engine.realtime import (  # noqa: F401  (re-exported: the servo's public names)
    FIFO_PRIORITY,
    SPIN_S,
    ServoTiming,
    TimedClock,
    realtime_setup,
)
from studyctl.engine.servo_child import construct, servo_main
from studyctl.errors import DeviceError
from studyctl.plugins.interfaces import Request, TrialInfo
from studyctl.plugins.registry import load_plugin


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
    parent_pid: int = 0  # set by ServoProcess: the child stops when its parent goes away


def make_device_safe(spec: ServoSpec) -> str | None:
    """From the parent, after the servo child died: open the device and close it again, which commands its safe
    state (the device's own watchdog is the backstop when this fails). Returns None or why it could not."""
    try:
        device = construct(load_plugin("device", spec.device), params=dict(spec.device_params), scene=None,
                           rng=np.random.default_rng(0))
        device.open()
        device.close()
    except Exception as exc:  # the device may be the reason the child died
        return f"{type(exc).__name__}: {exc}"
    return None


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
    # wall seconds from asking for the trial to its time 0 (spawn and imports on a new process, plugins built, open)
    start_s: float = float("nan")


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




SinkEvent = Callable[[float, str, Mapping[str, Any]], None]
SinkSample = Callable[[float, Mapping[str, float]], None]


class ServoProcess:
    """A servo process for a whole session: spawned at the first trial, reused by the next ones, ended by
    :meth:`close` (or the ``with`` block). A trial whose child died or failed is not reused: the next trial starts
    a new one. ``pid`` is the running child's (None before the first trial and after close)."""

    def __init__(self) -> None:
        self._proc: Any = None
        self._to_child: Any = None
        self._from_child: Any = None
        self._n = 0
        self.spawned = 0  # processes started so far (a session's figure: 1 unless a child died)

    def __enter__(self) -> ServoProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None and self._proc.is_alive() else None

    def _ensure(self) -> None:
        if self._proc is not None and self._proc.is_alive():
            return
        self._discard()
        ctx = mp.get_context("spawn")
        # two one-way pipes: the child writes from the loop's own thread (no queue feeder thread there)
        child_in, self._to_child = ctx.Pipe(duplex=False)
        self._from_child, child_out = ctx.Pipe(duplex=False)
        proc = ctx.Process(target=servo_main, args=(child_in, child_out, os.getpid()), name="studyctl-servo",
                           daemon=True)
        with _main_not_rerun():
            proc.start()
        child_in.close()
        child_out.close()
        self._proc = proc
        self.spawned += 1

    def _discard(self, timeout_s: float = 2.0) -> None:
        proc, self._proc = self._proc, None
        if proc is not None and proc.is_alive():
            self._send(("quit",))  # it ends between trials; a child stuck in a trial is terminated below
        if proc is not None:
            proc.join(timeout=timeout_s)
            if proc.is_alive():
                proc.terminate()
                proc.join(timeout=2.0)
        for conn in (self._to_child, self._from_child):
            if conn is not None:
                with contextlib.suppress(OSError):
                    conn.close()
        self._to_child = self._from_child = None

    def close(self) -> None:
        """End the servo process (it finishes nothing: call between trials)."""
        self._discard(timeout_s=5.0 if self._proc is not None and self._proc.is_alive() else 0.0)

    def _send(self, msg: tuple) -> None:
        with contextlib.suppress(OSError, ValueError):  # a dead child: noticed by the receiving side
            self._to_child.send(msg)

    def run_trial(
        self,
        spec: ServoSpec,
        *,
        on_event: SinkEvent | None = None,
        on_sample: SinkSample | None = None,
        requests: Callable[[], list[Request]] | None = None,
        should_stop: Callable[[], str | None] | None = None,
        poll_s: float = 0.005,
        start_timeout_s: float = 60.0,
    ) -> ServoResult:
        """Run one trial in the servo process; call the sinks here, in the parent, as data arrives.

        ``requests`` is polled every ``poll_s`` for the person's requests (scan, report, finish), which are
        forwarded to the loop; ``should_stop`` likewise (a reason string ends the trial). Raises
        :class:`~studyctl.errors.DeviceError` if the child fails (a plugin bug's traceback is in the message; a
        device's own error is passed on as it is) or dies; the device is then put in its safe state from here.
        """
        if not spec.parent_pid:
            spec = replace(spec, parent_pid=os.getpid())
        started = time.monotonic()
        self._ensure()
        self._n += 1
        n = self._n
        self._send(("trial", n, spec))
        state = _TrialState()
        try:
            while state.outcome is None and state.error is None:
                if requests is not None:
                    for r in requests():
                        self._send(("request", n, r.kind, dict(r.payload)))
                if should_stop is not None and not state.stop_sent:
                    reason = should_stop()
                    if reason:
                        self._send(("stop", n, reason))
                        state.stop_sent = True
                msg = self._receive(poll_s, state, started, start_timeout_s + spec.info.time_limit_s)
                if msg is not None and msg[0] == n:
                    state.take(msg[1:], started, on_event, on_sample)
        except BaseException:
            self._send(("stop", n, "abort"))  # Ctrl-C or a failing sink here: the child ends the trial safely
            self._discard(timeout_s=5.0)
            raise
        if state.error is not None or state.outcome is None:
            self._discard(timeout_s=5.0)  # a failed or dead child is not reused
            what, detail = state.error or ("no outcome", "")
            if state.died or detail:
                why = make_device_safe(spec)
                what += " (safe state commanded from this process)" if why is None else (
                    f"; putting the device in its safe state from here failed ({why}), its own watchdog is the "
                    "backstop")
            if not state.died and not detail:  # the device's own error (absent, busy …), already worded for the user
                raise DeviceError(what)
            raise DeviceError(f"servo process failed: {what}" + (f"\n{detail}" if detail else ""))
        out = state.outcome
        return ServoResult(ended_by=out["ended_by"], duration_s=out["duration_s"], ticks=out["ticks"],
                           scans=out["scans"], reports=out["reports"], events=out["events"], timing=state.timing,
                           rt=state.rt, memory=state.memory, start_s=state.start_s)

    def _receive(self, poll_s: float, state: _TrialState, started: float, limit_s: float) -> tuple | None:
        """The child's next message, or None; records in ``state`` a child that died or ran out of time."""
        conn, proc = self._from_child, self._proc
        try:
            if conn.poll(poll_s):
                return conn.recv()
        except (EOFError, OSError):
            pass  # the child's end closed: it died (or is dying)
        if not proc.is_alive() or conn.closed:
            try:  # its last messages may still be in the pipe
                if conn.poll(1.0):
                    return conn.recv()
            except (EOFError, OSError):
                pass
            proc.join(timeout=1.0)
            state.died = True
            state.error = (f"the servo process ended without a result (exit code {proc.exitcode})", "")
        elif time.monotonic() - started > limit_s:
            state.error = ("the servo process did not finish in time", "")
        return None


@dataclass
class _TrialState:
    """What the parent has received of one trial so far."""

    outcome: dict[str, Any] | None = None
    timing: ServoTiming | None = None
    rt: dict[str, Any] = field(default_factory=dict)
    memory: dict[str, Any] | None = None
    start_s: float = float("nan")
    error: tuple[str, str] | None = None
    died: bool = False
    stop_sent: bool = False

    def take(self, msg: tuple, started: float, on_event: SinkEvent | None, on_sample: SinkSample | None) -> None:
        kind = msg[0]
        if kind == "samples":
            if on_sample is not None:
                names = msg[1]
                for t, row in msg[2]:
                    on_sample(t, dict(zip(names, row, strict=True)))
        elif kind == "event":
            _, t, ev_kind, payload = msg
            if ev_kind == "servo_clock":
                self.start_s = time.monotonic() - started
            if ev_kind == "servo_timing":
                self.timing = ServoTiming(**{k: v for k, v in payload.items() if k in _TIMING_FIELDS})
                self.rt = dict(payload.get("rt") or {})
            if on_event is not None:
                on_event(t, ev_kind, payload)
        elif kind == "memory":
            self.memory = msg[1]
        elif kind == "outcome":
            self.outcome = msg[1]
        elif kind == "error":
            self.error = (msg[1], msg[2])


def run_trial_in_servo_process(spec: ServoSpec, **kwargs: Any) -> ServoResult:
    """One trial in a servo process of its own (tools and benches; a session reuses one :class:`ServoProcess`).
    Keywords as :meth:`ServoProcess.run_trial`."""
    with ServoProcess() as servo:
        return servo.run_trial(spec, **kwargs)

