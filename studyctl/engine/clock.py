"""Clocks. The same engine code runs on a real monotonic clock (people, hardware) and on a
simulated one (virtual participants, tests) that advances as fast as the computation allows."""

from __future__ import annotations

import time
from typing import Protocol

from studyctl.errors import UsageError


class Clock(Protocol):
    simulated: bool

    def now(self) -> float:
        """Seconds on this clock (monotonic)."""

    def sleep_until(self, t: float) -> None:
        """Return at (or just after) clock time ``t``."""


class RealClock:
    """Monotonic wall clock; sleeps coarsely then spins the last half-millisecond for precise pacing."""

    simulated = False

    def __init__(self) -> None:
        self._origin = time.perf_counter()

    def now(self) -> float:
        return time.perf_counter() - self._origin

    def sleep_until(self, t: float) -> None:
        remaining = t - self.now()
        if remaining > 0.0015:
            time.sleep(remaining - 0.001)
        while self.now() < t:
            pass


class SimulatedClock:
    """A clock that jumps to whatever time is asked for; a 90 s trial costs only its computation."""

    simulated = True

    def __init__(self, start: float = 0.0) -> None:
        self._t = float(start)

    def now(self) -> float:
        return self._t

    def sleep_until(self, t: float) -> None:
        if t > self._t:
            self._t = float(t)

    def advance(self, dt: float) -> None:
        self._t += float(dt)

    def child(self) -> SimulatedClock:
        """A fresh clock of the same kind starting at 0 (one per trial: exact trial times)."""
        return SimulatedClock(0.0)


class PacedClock(SimulatedClock):
    """A simulated clock held to at most ``speed`` × real time (watch a virtual run, or catch it mid-step).

    Results are those of :class:`SimulatedClock` (the same simulated times); only wall time differs.
    """

    def __init__(self, speed: float, start: float = 0.0) -> None:
        if not speed > 0:
            raise UsageError(f"clock speed must be > 0, got {speed!r}")
        super().__init__(start)
        self.speed = float(speed)
        self._origin_sim = float(start)
        self._origin_wall = time.perf_counter()

    def sleep_until(self, t: float) -> None:
        if t <= self._t:
            return
        wait = self._origin_wall + (t - self._origin_sim) / self.speed - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        self._t = float(t)

    def advance(self, dt: float) -> None:
        self.sleep_until(self._t + float(dt))

    def child(self) -> PacedClock:
        return PacedClock(self.speed, 0.0)
